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


@pytest.mark.parametrize(
    "change, message",
    [
        (("sigma = 0.055", 'sigma = "fine"'), "layers[1].sigma (layers of subdetector 'ut', z = 2327.5 … 2642.5): "
                                              "is 'fine', expected a finite number"),
        (("sigma = 0.055", "sigma = true"), "layers[1].sigma"),
        (("sigma = 0.055", "sigma = inf"), "layers[1].sigma"),
        (("stereo_deg = [0.0, 5.0, -5.0, 0.0]", 'stereo_deg = [0.0, "5", -5.0, 0.0]'),
         "layers[1].stereo_deg (layers of subdetector 'ut'"),
        (("station = [1, 1, 1, 1,", "station = [1.5, 1, 1, 1,"), "layers[2].station"),
        (('kind = "strip"', "kind = 1"), "layers[1].kind"),
        (("half_x = 770.0", "half_x = [770.0]"), "layers[1].half_x"),
        (("half_x = 770.0", "half_x = 0.0"), "layers[1].half_x must be > 0"),
        (("b0 = -1.03", 'b0 = "-1.03"'), "field.b0"),
        (("spacing = 100.0", "spacing = nan"), "field_map.spacing"),
        (("x_range = [-4000.0, 4000.0]", "x_range = [4000.0]"), "field_map.x_range"),
        (("half_width = 4000.0", 'half_width = "wide"'), "envelope.half_width"),
        (('name = "rich1-exit"', "name = 3"), "passive[1].name"),
        (("z = 1100.0", 'z = "1100"'), "passive[0].z"),
        (('type = "velo"', "type = 0"), "steps[0].type"),
        (('name = "lhcb-like"', "name = 1"), ": name: is 1, expected a string"),
    ],
)
def test_geometry_values_of_the_wrong_type(change, message):
    """Issue 13 case 6: every key has a type, checked on load (was a TypeError for sigma = "fine")."""
    text = load_geometry("lhcb-like").text
    assert change[0] in text
    with pytest.raises(InputError) as err:
        parse_geometry(text.replace(*change, 1), source="mine.toml")
    assert str(err.value).startswith("mine.toml: ") and "\n" not in str(err.value)
    assert message in str(err.value)
