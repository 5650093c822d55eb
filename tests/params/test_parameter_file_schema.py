"""Issue 13 case 11: a parameter file is checked against the geometry on load: one slot per
layer, finite numbers, the coefficient counts each step type reads, the UT→SciFi table.
Before, NaN, 10 of 68 slots or 5 of 50 coefficients were accepted (efficiency 0, every
track `ok`)."""

import json
from importlib import resources

import pytest

from pkf.errors import InputError
from pkf.geometry import load_geometry
from pkf.params.parameter_set import load_parameters


@pytest.fixture(scope="module")
def shipped():
    return {name: json.loads(resources.files("pkf.params").joinpath("data", f"{name}.json").read_text())
            for name in ("lhcb-like", "telescope")}


def _load(tmp_path, data, geometry="lhcb-like"):
    path = tmp_path / "params.json"
    path.write_text(json.dumps(data))
    return load_parameters(load_geometry(geometry), path)


def _changed(data, change):
    copy = json.loads(json.dumps(data))
    change(copy)
    return copy


@pytest.mark.parametrize("geometry", ["lhcb-like", "telescope"])
def test_shipped_files_pass(tmp_path, shipped, geometry):
    _load(tmp_path, shipped[geometry], geometry)  # telescope: 15 coefficients per slot (no degree-4 terms)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda p: p["slots"][60]["extrapolation"].__setitem__(3, float("nan")),
         "slots[60].extrapolation[3] is nan: coefficients must be finite numbers"),
        (lambda p: p["slots"][0]["noise"].__setitem__(1, float("inf")), "slots[0].noise[1] is inf"),
        (lambda p: p["slots"][5]["extrapolation"].__setitem__(0, "1.0"), "slots[5].extrapolation[0] is '1.0'"),
        (lambda p: p["slots"][5]["extrapolation"].__setitem__(0, True), "slots[5].extrapolation[0] is True"),
        (lambda p: p.__setitem__("slots", p["slots"][:10]),
         "'slots' has 10 entries; geometry 'lhcb-like' needs one per layer (68)"),
        (lambda p: p["slots"][60].__setitem__("extrapolation", p["slots"][60]["extrapolation"][:5]),
         "slots[60].extrapolation has 5 coefficients; the 'scifi' step leaving layer 60 needs 15 to 50"),
        (lambda p: p["slots"][51].__setitem__("extrapolation", p["slots"][51]["extrapolation"][:8]),
         "the 'velo_to_ut' step leaving layer 51 needs 9 to 50"),
        (lambda p: p["slots"][3].__setitem__("noise", p["slots"][3]["noise"][:3]), "slots[3].noise has 3 coefficients"),
        (lambda p: p["slots"][3]["noise"].extend([0.0]), "slots[3].noise has 7 coefficients"),
        (lambda p: p["slots"].reverse(), "slots[0]: expected an object with \"slot\": 0"),
        (lambda p: p.__setitem__("ut_to_scifi", None), "'ut_to_scifi' is None; geometry 'lhcb-like' has a ut_to_scifi step"),
    ],
)
def test_bad_coefficients_are_one_line_errors(tmp_path, shipped, change, message):
    with pytest.raises(InputError) as err:
        _load(tmp_path, _changed(shipped["lhcb-like"], change))
    text = str(err.value)
    assert text.startswith(f"--params {tmp_path / 'params.json'}: ") and "\n" not in text
    assert message in text


def test_shorter_sets_of_older_files_still_load(tmp_path, shipped):
    """A UT/SciFi set of 15 (eq. 14 without the degree-4 terms) and noise without the floor
    and straggling terms are valid: absent coefficients are zero."""
    def shorten(p):
        for slot in p["slots"][52:]:
            slot["extrapolation"] = slot["extrapolation"][:15]
            slot["noise"] = slot["noise"][:4]
    params = _load(tmp_path, _changed(shipped["lhcb-like"], shorten))
    assert (params.extrapolation[60, 15:] == 0).all() and (params.noise[60, 4:] == 0).all()
