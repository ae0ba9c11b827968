"""The examples in the docstrings of the main entry points run and print what they show (doctest)."""

import doctest
import importlib

import pytest

ENTRY_POINTS = (
    "uiest.system.System.from_functions",
    "uiest.system.System.from_ode",
    "uiest.simulate.simulate",
    "uiest.detectability.strong.certify_strong_detectability",
    "uiest.design.design_uise",
    "uiest.estimators.uise.UISE",
    "uiest.estimate",
    "uiest.analysis.analyse.analyse",
)
"""The objects (functions, classes, methods, modules) whose docstrings carry an example, by dotted path."""

FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _resolve(path: str) -> object:
    """The object at a dotted path: the longest importable module prefix, then attributes."""
    parts = path.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for name in parts[cut:]:
            obj = getattr(obj, name)
        return obj
    raise ImportError(path)


def _run_examples(obj: object, name: str) -> doctest.TestResults:
    """Run the examples of ``obj``'s own docstring (not those of its members)."""
    tests = [test for test in doctest.DocTestFinder(recurse=False).find(obj, name) if test.examples]
    assert tests, f"{name}: no example in its docstring"
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    for test in tests:
        runner.run(test)
    return runner.summarize(verbose=False)


@pytest.mark.parametrize("path", ENTRY_POINTS)
def test_the_entry_points_examples_run(path):
    results = _run_examples(_resolve(path), path)
    assert results.failed == 0, f"{path}: {results.failed} of {results.attempted} examples failed (output above)"


def test_a_broken_example_fails():
    def broken() -> None:
        """An example whose shown output is wrong.

        >>> 1 + 1
        3
        """

    def raising() -> None:
        """An example that raises.

        >>> from uiest.models import closed_form
        >>> closed_form.no_such_function()
        """

    for function in (broken, raising):
        assert _run_examples(function, function.__name__).failed == 1


def test_a_docstring_without_an_example_is_refused():
    def silent() -> None:
        """No example here."""

    with pytest.raises(AssertionError, match="no example"):
        _run_examples(silent, "silent")
