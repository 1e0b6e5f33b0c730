"""The library examples run as written: the README's Python example and examples/library.ipynb.

The README's code block is cut out of README.md and executed, so it cannot drift from the
API; the notebook is executed cell by cell with nbclient on a ``python3`` kernel that runs
this interpreter (a kernel spec written for the test, so a user's own ``python3`` kernel
elsewhere on the machine is never picked up).
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
NOTEBOOK = ROOT / "examples" / "library.ipynb"


def _readme_library_code() -> str:
    """The ``python`` code blocks of the README's section "The library", in order."""
    text = README.read_text(encoding="utf-8")
    m = re.search(r"^## The library\n(.*?)^## ", text, flags=re.S | re.M)
    assert m, "README.md has no section '## The library'"
    blocks = re.findall(r"^```python\n(.*?)^```", m.group(1), flags=re.S | re.M)
    assert blocks, "the README's section 'The library' has no python code block"
    return "\n".join(blocks)


def test_readme_example_uses_public_names_only():
    code = _readme_library_code()
    imports = re.findall(r"^\s*(?:from|import)\s+([\w.]+)", code, flags=re.M)
    assert "encdesign" in imports
    for name in imports:
        assert not any(part.startswith("_") for part in name.split(".")), name
    assert not re.search(r"\bed\.\w*\._", code), "a private module reached through ed."


def test_readme_library_example_runs(capsys):
    code = _readme_library_code()
    namespace: dict = {"__name__": "__readme__"}
    exec(compile(code, str(README), "exec"), namespace)  # noqa: S102 - the README's own code
    out = capsys.readouterr().out
    assert "reference head at" in out and "checked_yield" in out
    assert namespace["solution"].ok
    assert namespace["mc"].ok and namespace["mc"].n == 1000


@pytest.fixture
def python3_kernel(tmp_path, monkeypatch):
    """A ``python3`` kernel spec for this interpreter, found before any other."""
    from ipykernel.kernelspec import write_kernel_spec

    data = tmp_path / "jupyter"
    spec = write_kernel_spec(data / "kernels" / "python3")
    monkeypatch.setenv("JUPYTER_PATH", str(data))
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")
    # the kernel imports this checkout, whatever the installed package points at
    path = os.environ.get("PYTHONPATH", "")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(ROOT), path) if p))
    from jupyter_client.kernelspec import KernelSpecManager

    found = KernelSpecManager().get_kernel_spec("python3")
    assert Path(found.resource_dir) == Path(spec)
    assert found.argv[0] == sys.executable
    return "python3"


def test_example_notebook_runs(python3_kernel, tmp_path):
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), (
        "examples/library.ipynb is stored with outputs; clear them"
    )
    client = NotebookClient(
        nb,
        kernel_name=python3_kernel,
        timeout=600,
        resources={"metadata": {"path": str(tmp_path)}},
    )
    client.execute()
    text = "".join(
        o.get("text", "") + str(o.get("data", {}).get("text/plain", ""))
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.outputs
    )
    assert "reference head at" in text and "ok: True" in text
    assert "'checked_yield'" in text
    assert "hidden: vibration | verdict:" in text
