"""`load_parameters` reads a parameter file once per process and content (issue 14, deliverable 4)."""

from __future__ import annotations

import json
from importlib import resources

from pkf.geometry import load_geometry
from pkf.params.parameter_set import load_parameters


def test_a_parameter_file_is_read_once_and_again_when_it_changes(tmp_path):
    geometry = load_geometry("telescope")
    shipped = json.loads(resources.files("pkf.params").joinpath("data", "telescope.json").read_text())
    path = tmp_path / "p.json"
    path.write_text(json.dumps(shipped))
    first = load_parameters(geometry, path)
    assert load_parameters(geometry, path) is first  # the same file: not parsed again
    shipped["metadata"]["date"] = "changed"  # a changed file is read again
    path.write_text(json.dumps(shipped))
    changed = load_parameters(geometry, path)
    assert changed is not first
    assert changed.extrapolator(geometry) is not None
    assert load_parameters(geometry, None) is load_parameters(geometry, None)
