"""Detector description (layers, material planes), field models and the field map."""

from pkf.geometry.detector import (
    BUILTIN_GEOMETRIES,
    KIND_PIXEL,
    KIND_STRIP,
    SUBDETECTORS,
    Geometry,
    load_geometry,
    parse_geometry,
)
from pkf.geometry.field import (
    FIELD_DIPOLE,
    FIELD_MAP,
    FIELD_UNIFORM,
    FieldModel,
    build_field_map,
    dipole_field,
    field_at,
    uniform_field,
)

__all__ = [
    "BUILTIN_GEOMETRIES", "KIND_PIXEL", "KIND_STRIP", "SUBDETECTORS", "Geometry",
    "load_geometry", "parse_geometry", "FIELD_DIPOLE", "FIELD_MAP", "FIELD_UNIFORM",
    "FieldModel", "build_field_map", "dipole_field", "field_at", "uniform_field",
]
