"""Geometry files: the built-ins match DESIGN §3 and bad files give one-line errors."""

import numpy as np
import pytest

from pkf.errors import InputError
from pkf.geometry import KIND_PIXEL, KIND_STRIP, load_geometry, parse_geometry


def test_lhcb_like_layers_match_design():
    g = load_geometry("lhcb-like")
    assert g.n_layers == 52 + 4 + 12
    assert np.all(np.diff(g.layer_z) > 0)
    velo = g.subdetector_layers("velo")
    ut = g.subdetector_layers("ut")
    scifi = g.subdetector_layers("scifi")
    assert (velo.size, ut.size, scifi.size) == (52, 4, 12)
    assert g.layer_z[velo[0]] == -287.5 and g.layer_z[velo[-1]] == 750.0
    assert np.all(g.layer_kind[velo] == KIND_PIXEL)
    assert np.all(g.layer_kind[ut] == KIND_STRIP)
    assert np.allclose(np.degrees(g.layer_stereo[ut]), [0, 5, -5, 0])
    assert np.allclose(g.layer_z[scifi][[0, 4, 8]], [7826, 8508, 9193])
    assert np.allclose(g.layer_sigma[[velo[0], ut[0], scifi[0]]], [0.0125, 0.055, 0.080])
    planes = g.planes
    assert planes.z.size == 70 and np.all(np.diff(planes.z) > 0)
    passive = planes.layer < 0
    assert np.allclose(planes.z[passive], [1100, 2100])
    assert np.allclose(planes.x_over_x0[passive], [0.04, 0.03])
    # VELO modules alternate sides, the first covers x <= +5 (left)
    assert list(planes.side[:4]) == [1, 2, 1, 2]
    assert g.steps[("ut", "scifi")] == "ut_to_scifi"


def test_telescope():
    g = load_geometry("telescope")
    assert g.n_layers == 10
    assert np.allclose(np.diff(g.layer_z), 100.0)
    assert np.allclose(g.field.evaluate([0], [0], [500]), [[0, 1, 0]])


def test_hash_ignores_comments_but_not_content():
    g = load_geometry("telescope")
    same = parse_geometry("# a comment\n" + g.text)
    assert same.content_hash == g.content_hash
    other = parse_geometry(g.text.replace("sigma = 0.01", "sigma = 0.02"))
    assert other.content_hash != g.content_hash


def test_geometry_from_file(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(load_geometry("telescope").text.replace('name = "telescope"', 'name = "mine"'))
    assert load_geometry(path).name == "mine"


@pytest.mark.parametrize(
    "change, message",
    [
        (('kind = "pixel"', 'kind = "pad"'), "kind"),
        (("sigma = 0.01", "sigma = -0.01"), "sigma"),
        (('model = "uniform"', 'model = "solenoid"'), "field.model"),
        (("half_x = 1000.0", "half_x = 1000.0\nbogus = 1"), "bogus"),
        (('type = "ut"', 'type = "warp"'), "steps"),
        (("z = [100.0,", "z = [100.0, 100.0,"), "same z"),
        (("[field]", "[field"), "TOML"),
    ],
)
def test_bad_geometry_is_one_line_error(change, message):
    text = load_geometry("telescope").text.replace(*change)
    with pytest.raises(InputError) as err:
        parse_geometry(text, source="bad.toml")
    assert message in str(err.value)
    assert "\n" not in str(err.value)
    assert str(err.value).startswith("bad.toml")


def test_unknown_geometry_name():
    with pytest.raises(InputError, match="unknown geometry"):
        load_geometry("atlas")
