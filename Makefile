# The two commands of the README. Both create .venv and install the project
# with every extra on first use (re-installs when pyproject.toml changes).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test fuzz bench clean-venv

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q -e '.[farm,train,distributed,dev]'
	touch $@

demo: $(STAMP)
	$(PY) tools/demo.py

test: $(STAMP)
	$(PY) -m pytest -q

clean-venv:
	rm -rf $(VENV)

# The fuzz suite at full size (docs/RELIABILITY.md): RELIGHT_FUZZ_EXAMPLES generated cases per
# property (default 1500: about 11,000 in all) instead of the dozen `make test` runs, under a
# 4 GiB address-space limit (an allocation sized by a forged header fails the run) and an
# hour's timeout; prints the cases and the outcomes by type.
fuzz: $(STAMP)
	ulimit -v 4194304 && RELIGHT_FUZZ_PROFILE=fuzz PYTHONPATH=tests timeout 3600 \
		$(PY) -m pytest -q -p fuzz_support tests/test_fuzz_loaders.py tests/test_fuzz_sh.py tests/test_fuzz_cli.py
