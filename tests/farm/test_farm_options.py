"""The farm's scene options: one class, validated, and a lossless JSON round trip."""

import json

import pytest

from farm.synthesis.scene_options import SceneOptions


def test_json_round_trip_is_lossless():
    opts = SceneOptions(resolution=64, lights=2, passes=frozenset({"prt"}), specular="off")
    back = SceneOptions.from_json(json.loads(json.dumps(opts.to_json())))
    assert back == opts and isinstance(back.passes, frozenset)


def test_expected_channels_follow_the_dataset_table():
    # 12 always-present channels (the head mask since issue 37); prt adds n transport + 6 per light;
    # pt adds 3 per light; body adds its normal, coverage and depth
    assert SceneOptions(sh_order=4, lights=4).expected_channels() == 12 + 25 + 24 + 12 + 5
    assert SceneOptions(sh_order=2, lights=1, passes=frozenset({"pt"})).expected_channels() == 12 + 3
    assert SceneOptions(lights=3, passes=frozenset({"prt"})).path_traced_images() == 0


@pytest.mark.parametrize("change, word", [
    ({"resolution": 4}, "resolution"), ({"lights": 0}, "lights"), ({"denoise": 1}, "denoise"),
    ({"passes": frozenset({"pt", "xyz"})}, "passes"), ({"specular": "maybe"}, "specular"),
    ({"light_pool": "test"}, "light_pool"), ({"sh_order": True}, "sh_order"),
    ({"denoise_prefilter": "FAST"}, "denoise_prefilter"),
])
def test_bad_values_are_named(change, word):
    with pytest.raises(ValueError, match=word):
        SceneOptions(**change).validate()


def test_sidecars_from_before_the_prefilter_option_read_as_accurate():
    """Older sidecars have no denoise_prefilter: they were rendered with OIDN's ACCURATE prefilter."""
    old = SceneOptions().to_json()
    del old["denoise_prefilter"]
    assert SceneOptions.from_json(old).denoise_prefilter == "accurate"
    assert SceneOptions().denoise_prefilter == "fast"
    assert SceneOptions.from_json(SceneOptions().to_json()).denoise_prefilter == "fast"
