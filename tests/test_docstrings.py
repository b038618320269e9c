"""The API reference of the filter core, the contract and the registry: every public function and
method says its parameters and what it returns (numpydoc), so the reference built from them
(mkdocs, in CI) documents the extension API a researcher writes a filter against."""

from __future__ import annotations

import dataclasses
import importlib
import inspect

import pytest

DOCUMENTED = [
    "mazelab.contract",
    "mazelab.registry",
    "mazelab.declaration",
    "mazelab.simulation:record_steps",  # the recording loop a study calls too
    "mazelab.smc",
    "mazelab.smoothing",
    "mazelab.learning",
]


def public_callables(module_name: str):
    """(qualified name, function) of the module's public functions and its public classes' methods
    ("module:name" for one of them)."""
    module_name, _, only = module_name.partition(":")
    module = importlib.import_module(module_name)
    for name in [only] if only else getattr(module, "__all__", []):
        obj = getattr(module, name)
        if getattr(obj, "__module__", None) != module_name:
            continue
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj):
            fields = {f.name for f in dataclasses.fields(obj)} if dataclasses.is_dataclass(obj) else set()
            for attribute, value in vars(obj).items():
                function = value.__func__ if isinstance(value, (classmethod, staticmethod)) else value
                if attribute.startswith("_") or attribute in fields or not inspect.isfunction(function):
                    continue
                yield f"{name}.{attribute}", function


@pytest.mark.parametrize("module_name", DOCUMENTED)
def test_every_public_function_says_its_parameters_and_what_it_returns(module_name):
    undocumented = []
    for name, function in public_callables(module_name):
        doc = inspect.getdoc(function) or ""
        signature = inspect.signature(function)
        parameters = [p for p in signature.parameters if p not in ("self", "cls")]
        returns = signature.return_annotation not in (inspect.Signature.empty, None, "None")
        if not doc or (parameters and "Parameters\n---" not in doc) or (returns and "Returns\n---" not in doc):
            undocumented.append(name)
    assert undocumented == [], f"{module_name}: no numpydoc Parameters/Returns for {undocumented}"
