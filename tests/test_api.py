"""The public API: a curated top level, one error root, subpackages that are not shadowed, and
studies that use only public names (``docs/DEVELOPING.md``)."""

from __future__ import annotations

import ast
import importlib
import subprocess
import sys
import types
from pathlib import Path

import pytest

import encdesign

ROOT = Path(__file__).resolve().parent.parent
SUBPACKAGES = ("physics", "io", "design", "diagnose", "calibrate", "simulate", "cli")


def _public(mod: types.ModuleType) -> set[str]:
    return {
        n
        for n in dir(mod)
        if not n.startswith("_") and not isinstance(getattr(mod, n), types.ModuleType)
    }


def test_top_level_is_curated():
    names = encdesign.__all__
    assert len(names) <= 70, f"{len(names)} top-level names (at most 70)"
    assert len(set(names)) == len(names), "a name is listed twice in __all__"
    # what the package namespace holds is exactly what __all__ says (no silent extras)
    assert _public(encdesign) == set(names)


@pytest.mark.parametrize("sub", SUBPACKAGES)
def test_subpackages_are_attributes_and_export_what_they_list(sub):
    mod = importlib.import_module(f"encdesign.{sub}")
    assert getattr(encdesign, sub) is mod
    for n in getattr(mod, "__all__", ()):
        assert hasattr(mod, n), f"encdesign.{sub}.__all__ lists {n!r}, which is not there"


def test_import_diagnose_as_gives_the_subpackage():
    """``encdesign.diagnose`` is the subpackage (its entry point is ``.diagnose``); run in a
    fresh interpreter so that nothing imported earlier decides the attribute."""
    code = (
        "import types, sys\n"
        "import encdesign.diagnose as d\n"
        "import encdesign\n"
        "assert isinstance(d, types.ModuleType), type(d)\n"
        "assert d is sys.modules['encdesign.diagnose'] is encdesign.diagnose\n"
        "assert callable(d.diagnose) and not isinstance(d.diagnose, types.ModuleType)\n"
        "from encdesign.diagnose import diagnose\n"
        "assert diagnose is d.diagnose\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_one_error_root():
    from encdesign._errors import input_error

    for cls, builtin in (
        (encdesign.EncdesignInputError, ValueError),
        (encdesign.OptimisationError, RuntimeError),
        (encdesign.DistributedError, RuntimeError),
        (encdesign.DiagnosisError, RuntimeError),
    ):
        assert issubclass(cls, encdesign.EncdesignError)
        assert issubclass(cls, builtin)  # older ``except ValueError`` code still works
    assert encdesign.design.OptimisationError is encdesign.OptimisationError
    assert isinstance(input_error("f", "bad"), encdesign.EncdesignError)
    with pytest.raises(encdesign.EncdesignError):
        encdesign.load_recording(ROOT / "no-such-recording.toml")
    with pytest.raises(encdesign.EncdesignError):  # a model invariant (was a bare ValueError)
        encdesign.design.LayoutDesign(radius_m=0.0254, head_angles_rad=[0.0])


def _private_imports(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        mods = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            mods = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            mods = [a.name for a in node.names]
        for m in mods:
            parts = m.split(".")
            if parts[0] == "encdesign" and any(p.startswith("_") for p in parts[1:]):
                out.append(f"{path.name}:{node.lineno}: {m}")
                break
    return out


def test_no_study_imports_a_private_module():
    bad = [b for f in sorted((ROOT / "studies").glob("*.py")) for b in _private_imports(f)]
    assert not bad, "studies import private modules or names:\n" + "\n".join(bad)


def test_private_import_checker_itself(tmp_path):
    f = tmp_path / "s.py"
    f.write_text(
        "from encdesign.io._study import write_json\n"
        "from encdesign.design import _objectives\n"
        "import encdesign.physics._sds\n"
        "from encdesign.io import write_json\n"
    )
    assert len(_private_imports(f)) == 3


def test_objective_names_kept_once():
    """``encdesign.objectives`` re-exports ``design._objectives.__all__`` rather than a copy."""
    from encdesign import objectives
    from encdesign.design import _objectives, _registry

    assert objectives.__all__ == [*_objectives.__all__, "PROBLEM_OBJECTIVES"]
    for n in _objectives.__all__:
        assert getattr(objectives, n) is getattr(_objectives, n)
    assert objectives.PROBLEM_OBJECTIVES is _registry.PROBLEM_OBJECTIVES


def test_import_is_lazy():
    """``import encdesign`` and the diagnose command import no subpackage they do not run
    (``encdesign._lazy``; docs/scale.md, "Start"): a diagnosis never imports the design
    drivers (their optimisers), the simulators, the calibration or ``tqdm`` (a progress bar
    imports it when it is made); run in a fresh
    interpreter so that nothing imported earlier decides it."""
    code = (
        "import sys\n"
        "import encdesign, encdesign.cli._diagnose\n"
        "never = ('encdesign.design', 'encdesign.simulate', 'encdesign.calibrate', 'optimistix',\n"
        "         'tqdm')\n"
        "early = never + ('encdesign.diagnose', 'encdesign.physics._ellipse', 'scipy.optimize')\n"
        "got = [m for m in early if m in sys.modules]\n"
        "assert not got, got\n"
        "import encdesign.diagnose\n"
        "got = [m for m in never if m in sys.modules]\n"
        "assert not got, got\n"
        "assert encdesign.Disk is encdesign.physics.Disk\n"
        "from encdesign import load_problem\n"
        "assert 'encdesign.design' in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


@pytest.mark.parametrize("pkg", ["encdesign", "encdesign.physics"])
def test_lazy_names_are_their_modules_objects(pkg):
    """Every name a lazy ``__init__`` lists resolves to the object of the module it names,
    and ``dir`` lists it."""
    from encdesign._lazy import exports_of

    mod = importlib.import_module(pkg)
    assert mod.__file__ is not None
    table = exports_of(mod.__file__)
    assert len(table) > 10
    for name, (base, attr) in table.items():
        if base.strip(".") == "":
            want = importlib.import_module(f"{base}{attr}", pkg)
        else:
            want = getattr(importlib.import_module(base, pkg), attr)
        assert getattr(mod, name) is want, name
        assert name in dir(mod)
    with pytest.raises(AttributeError, match="no attribute"):
        mod.not_a_name  # noqa: B018
