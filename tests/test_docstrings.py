"""The runnable examples in ctfit's docstrings run and print what they say (``doctest``)."""

import doctest
import importlib
import inspect
from pathlib import Path

import numpy as np
import pytest

import ctfit

PACKAGE = Path(__file__).resolve().parents[1] / "ctfit"
MODULES = sorted(
    ".".join(("ctfit", *p.relative_to(PACKAGE).with_suffix("").parts)).removesuffix(".__init__")
    for p in PACKAGE.rglob("*.py")
)


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    module = importlib.import_module(name)
    # NumPy's own array printing, whatever ran before: colour-science switches it to legacy="1.13"
    # when it is imported (done first, so that this context undoes it).
    importlib.import_module("colour")
    with np.printoptions(legacy=False):
        result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE | doctest.ELLIPSIS, verbose=False)
    assert result.failed == 0


def test_public_names_have_examples():
    """Every public function and class of ``ctfit`` has an example that doctest runs (not skipped)."""
    public = [(name, getattr(ctfit, name)) for name in ctfit.__all__]
    checked = [(name, obj) for name, obj in public if inspect.isfunction(obj) or (inspect.isclass(obj) and not issubclass(obj, Warning))]
    assert checked
    parser = doctest.DocTestParser()
    missing = [
        name
        for name, obj in checked
        if not any(not ex.options.get(doctest.SKIP) for ex in parser.get_examples(inspect.getdoc(obj) or "", name))
    ]
    assert not missing, f"public names without a runnable example in their docstring: {missing}"
