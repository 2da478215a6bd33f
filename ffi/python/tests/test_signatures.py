"""help() and inspect.signature show every function's parameters with their Python defaults
(PyO3 alone printed `...` for a default it cannot render, such as engine="lm")."""

import inspect

import pytest

import volver

FUNCTIONS = [
    name for name in volver.__all__ if callable(getattr(volver, name)) and name[0].islower()
]


def test_every_function_is_listed():
    assert len(FUNCTIONS) >= 12


@pytest.mark.parametrize("name", FUNCTIONS)
def test_every_default_is_a_python_value(name):
    function = getattr(volver, name)
    signature = inspect.signature(function)
    for parameter in signature.parameters.values():
        assert parameter.default is not Ellipsis, f"{name}({parameter.name}=...)"
    assert "..." not in (function.__text_signature__ or ""), name


def test_the_shown_defaults_are_those_that_apply():
    identify = inspect.signature(volver.identify).parameters
    assert identify["engine"].default == "lm"
    assert identify["objective"].default == "phi"
    assert identify["priors"].default == ()
    assert identify["data"].default is inspect.Parameter.empty
    assert identify["engine"].kind is inspect.Parameter.KEYWORD_ONLY
    compensate = inspect.signature(volver.compensate_points).parameters
    assert compensate["reversal_tolerance_um"].default == volver.REVERSAL_TOLERANCE_UM
    assert inspect.signature(volver.plan).parameters["criterion"].default == "i"


def test_an_unknown_keyword_is_refused():
    with pytest.raises(TypeError, match="unexpected keyword"):
        volver.describe(machin="xcfz")
