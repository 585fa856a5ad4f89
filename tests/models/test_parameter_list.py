"""The Strauss parameter list is written once (strauss_fit.models.material.STRAUSS_PARAMETERS):
the registry's Strauss model, the material, the names, ranges and groups derived from it
agree, and no other module of the package writes a list of the parameter names out."""

from __future__ import annotations

import ast
import collections
import dataclasses
import inspect
from pathlib import Path

import numpy as np

import strauss_fit
from strauss_fit.fitting.capture import HELD
from strauss_fit.fitting.capture_equivalence import MATERIAL
from strauss_fit.fitting.parameters import MATERIAL_SIZES, Layout
from strauss_fit.fitting.summary import SUMMARY_COLUMNS
from strauss_fit.models import material
from strauss_fit.models.material import (
    COLOR_RANGE,
    FRACTION_NAMES,
    OPAQUE_NAMES,
    PARAMETER_NAMES,
    PARAMETER_RANGES,
    REFLECTION_NAMES,
    SCALAR_NAMES,
    STRAUSS_PARAMETERS,
    Material,
    check_values,
)
from strauss_fit.models.reflectance import REFLECTANCE_MODELS, Parameter
from strauss_fit.models.reflectance._base import Parameter as BaseParameter

PACKAGE = Path(strauss_fit.__file__).parent
#: The one home of the list: the only module allowed to write it.
HOME = Path(material.__file__)

#: Literal lists of two or more parameter names that may stay, as (file, names in the order
#: written), each with the reason it is not the parameter list.
ALLOWED = collections.Counter(
    {
        # a priority (which parameter a degenerate fit holds first), not the parameter list
        ("strauss_fit/fitting/identifiability.py", ("ior", "transparency", "metalness", "smoothness", "color")): 1,
    }
)


def test_the_registry_holds_the_material_parameters():
    strauss = REFLECTANCE_MODELS["strauss"]
    assert strauss.parameters is STRAUSS_PARAMETERS
    assert all(p is q for p, q in zip(strauss.parameters, STRAUSS_PARAMETERS, strict=True))
    assert strauss.names == PARAMETER_NAMES
    assert strauss.nonlinear == FRACTION_NAMES
    # Parameter moved to a leaf module; the old import paths give the same class
    assert Parameter is BaseParameter
    assert all(type(p) is Parameter for p in STRAUSS_PARAMETERS)


def test_names_and_ranges_follow_the_parameters():
    assert PARAMETER_NAMES == tuple(p.name for p in STRAUSS_PARAMETERS)
    assert len(set(PARAMETER_NAMES)) == len(PARAMETER_NAMES)
    scalars = [p for p in STRAUSS_PARAMETERS if p.size == 1]
    assert list(PARAMETER_RANGES) == [p.name for p in scalars]
    assert all(PARAMETER_RANGES[p.name] == (p.low, p.high) for p in scalars)
    (color,) = [p for p in STRAUSS_PARAMETERS if p.size == 3]
    assert color.name == PARAMETER_NAMES[0]
    assert COLOR_RANGE == (color.low, color.high)


def test_the_named_groups():
    # written out here on purpose: the groups' meaning, pinned in order
    assert SCALAR_NAMES == ("smoothness", "metalness", "transparency", "ior") == PARAMETER_NAMES[1:]
    assert FRACTION_NAMES == ("smoothness", "metalness", "transparency")
    assert all(PARAMETER_RANGES[name] == (0.0, 1.0) for name in FRACTION_NAMES)
    assert REFLECTION_NAMES == ("color", "smoothness", "metalness", "transparency")
    assert OPAQUE_NAMES == ("color", "smoothness", "metalness")
    # every group keeps the order of PARAMETER_NAMES
    for group in (SCALAR_NAMES, FRACTION_NAMES, REFLECTION_NAMES, OPAQUE_NAMES):
        assert group == tuple(name for name in PARAMETER_NAMES if name in group)


def test_the_material_follows_the_list():
    assert [f.name for f in dataclasses.fields(Material)] == list(PARAMETER_NAMES)
    assert list(Material().to_dict()) == list(PARAMETER_NAMES)
    for function in (Material.__init__, check_values):
        arguments = [a for a in inspect.signature(function).parameters.values() if a.kind is a.POSITIONAL_OR_KEYWORD]
        arguments = [a for a in arguments if a.name != "self"]
        assert [a.name for a in arguments] == list(PARAMETER_NAMES)
        for argument, parameter in zip(arguments, STRAUSS_PARAMETERS):
            expected = np.broadcast_to(np.asarray(parameter.default, dtype=float), (parameter.size,))
            assert np.array_equal(
                np.broadcast_to(np.asarray(argument.default, dtype=float), (parameter.size,)), expected
            )
    assert Material().to_dict() == REFLECTANCE_MODELS["strauss"].to_dict(REFLECTANCE_MODELS["strauss"].defaults())


def test_what_the_fits_derive():
    assert list(MATERIAL_SIZES) == list(PARAMETER_NAMES)
    assert all(MATERIAL_SIZES[p.name] == p.size for p in STRAUSS_PARAMETERS)
    assert Layout(REFLECTION_NAMES).labels()[:3] == ["color_r", "color_g", "color_b"]
    for name, model in REFLECTANCE_MODELS.items():
        assert MATERIAL[name] == tuple(p.name for p in model.parameters if p.name not in HELD)
    assert MATERIAL["strauss"] == OPAQUE_NAMES
    scalars = [c for c in SUMMARY_COLUMNS if c in SCALAR_NAMES]
    deviations = [c[3:] for c in SUMMARY_COLUMNS if c.startswith("sd_") and c[3:] in SCALAR_NAMES]
    assert scalars == deviations == list(SCALAR_NAMES)


def _literal_lists(path: Path, root: Path) -> list[tuple[str, tuple[str, ...]]]:
    """Each tuple, list or set literal of ``path`` holding two or more parameter names, and
    each dict giving two or more of them one and the same value (a list in disguise)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            items = node.elts
        elif isinstance(node, ast.Dict) and len({ast.dump(v) for v in node.values}) == 1:
            items = node.keys
        else:
            continue
        names = tuple(e.value for e in items if isinstance(e, ast.Constant) and e.value in PARAMETER_NAMES)
        if len(names) >= 2:
            found.append((path.relative_to(root).as_posix(), names))
    return found


def test_the_scan_finds_a_written_out_list(tmp_path):
    module = tmp_path / "probe.py"
    module.write_text(
        'A = ("color", "ior")\n'
        'B = ["smoothness", 1, "metalness"]\n'
        'C = {"color": 1, "ior": 1}\n'
        'D = {"color": 3, "ior": 1}  # values of their own: data, not the list\n'
        'E = x["color"], "exposure"  # one name\n',
        encoding="utf-8",
    )
    found = _literal_lists(module, tmp_path)
    assert sorted(found) == [
        ("probe.py", ("color", "ior")),
        ("probe.py", ("color", "ior")),
        ("probe.py", ("smoothness", "metalness")),
    ]


def test_no_other_module_writes_the_list():
    # the production code: the library, the command line and the synthetic data
    found = collections.Counter()
    paths = [p for folder in ("strauss_fit", "cli", "data_synth") for p in (PACKAGE.parent / folder).rglob("*.py")]
    for path in sorted(paths):
        if path != HOME:
            found.update(_literal_lists(path, PACKAGE.parent))
    unexpected = sorted((found - ALLOWED).elements())
    assert not unexpected, (
        "lists of Strauss parameter names written out (derive them from strauss_fit.models.material: "
        f"PARAMETER_NAMES, SCALAR_NAMES, FRACTION_NAMES, REFLECTION_NAMES, OPAQUE_NAMES): {unexpected}"
    )
    stale = sorted((ALLOWED - found).elements())
    assert not stale, f"allowed lists that are gone: remove them from ALLOWED: {stale}"
