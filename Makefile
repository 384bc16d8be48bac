# The two commands of the README. Both create .venv and install the project
# with every extra on first use (re-installs when pyproject.toml changes).
# `make test` lints with ruff (pyproject.toml [tool.ruff]), then also makes .venv-b42 (bpy 4.2 LTS, Python 3.11) and .venv-b52 (bpy 5.2 LTS,
# Python 3.13: Blender 5.1+ embeds it) and runs the add-on's tests under each.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# Python 3.13 for the Blender 5.2 venv: the first candidate that runs as 3.13 (pyenv's own
# builds first: its shim fails when 3.13 is not the global version)
PYTHON313 ?= $(firstword $(foreach p,$(wildcard $(HOME)/.pyenv/versions/3.13*/bin/python3.13) $(shell command -v python3.13 2>/dev/null),$(shell $(p) -c 'import sys; print("$(p)" if sys.version_info[:2] == (3, 13) else "")' 2>/dev/null)))
# what runs under the other Blenders: the add-on (install, operators, save and reopen) and the golden
# relight; under 5.2 also the farm's Blender layer (Cycles AOVs, World mapping, skies; the farm uses
# Blender 5.0's API, so not 4.2; its bodies need torch, which Python 3.13 lacks here: -m "not anny")
ADDON_TESTS = $(wildcard tests/blender_addon/test_addon_*.py) tests/relight/network/test_relit_golden.py
FARM_BPY_TESTS = tests/farm/test_blender_mapping.py tests/farm/test_farm_scene.py -m "not anny"

.PHONY: demo test fuzz bench clean-venv

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q -e '.[farm,train,distributed,dev,video]'
	touch $@

.venv-b42/.installed: pyproject.toml
	test -x .venv-b42/bin/python || $(PYTHON) -m venv .venv-b42
	.venv-b42/bin/python -m pip install -q -e '.[blender42]'
	touch $@

.venv-b52/.installed: pyproject.toml
	@test -n "$(PYTHON313)" || { echo "make test: no Python 3.13 for the Blender 5.2 tests (pyenv install 3.13, or set PYTHON313=/path/to/python3.13)" >&2; exit 1; }
	test -x .venv-b52/bin/python || $(PYTHON313) -m venv .venv-b52
	.venv-b52/bin/python -m pip install -q -e '.[blender52]'
	touch $@

demo: $(STAMP)
	$(PY) tools/demo.py

test: $(STAMP) .venv-b42/.installed .venv-b52/.installed
	$(PY) -m ruff check .
	$(PY) -m pytest
	@echo "== the add-on under Blender 4.2 LTS (bpy 4.2.23, Python 3.11) =="
	RELIGHT_TORCH_PYTHON=$(abspath $(PY)) .venv-b42/bin/python -m pytest $(ADDON_TESTS)
	@echo "== the add-on under Blender 5.2 LTS (bpy 5.2.3, Python 3.13) =="
	RELIGHT_TORCH_PYTHON=$(abspath $(PY)) .venv-b52/bin/python -m pytest $(ADDON_TESTS) $(FARM_BPY_TESTS)

clean-venv:
	rm -rf $(VENV) .venv-b42 .venv-b52

# The fuzz suite at full size (docs/RELIABILITY.md): RELIGHT_FUZZ_EXAMPLES generated cases per
# property (default 1500: about 11,000 in all) instead of the dozen `make test` runs, under a
# 4 GiB address-space limit (an allocation sized by a forged header fails the run) and an
# hour's timeout; prints the cases and the outcomes by type.
fuzz: $(STAMP)
	ulimit -v 4194304 && RELIGHT_FUZZ_PROFILE=fuzz PYTHONPATH=tests/support timeout 3600 \
		$(PY) -m pytest -q -p fuzz_support tests/relight/files/test_fuzz_loaders.py tests/relight/lighting/test_fuzz_sh.py tests/relight/command/test_fuzz_cli.py tests/relight/command/test_fuzz_video.py
