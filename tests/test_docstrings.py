"""Every docstring example of the library runs: an example is documentation that a reader copies, and one
that no test runs rots (two raised ImportError before this test existed). A module whose import needs an
optional extra that is not installed is skipped, naming it."""
import doctest
import importlib
import pkgutil

import pytest

import adaptfilt

#: Top-level packages of the optional extras (pyproject.toml): without them their modules are skipped.
OPTIONAL = {"gymnasium", "stable_baselines3", "distributed", "dask", "numba", "rliable", "stonesoup", "filterpy"}
#: Importing the command's entry point would run the command.
NOT_IMPORTED = {"adaptfilt.__main__"}
MODULES = sorted(m.name for m in pkgutil.walk_packages(adaptfilt.__path__, "adaptfilt.") if m.name not in NOT_IMPORTED)


def test_the_walk_finds_the_library():
    assert {"adaptfilt.gaf", "adaptfilt.rules.stochastic", "adaptfilt.experiments.sweep", "adaptfilt.course.ungm_ukf"} <= set(MODULES)


@pytest.mark.parametrize("name", ["adaptfilt", *MODULES])
def test_docstring_examples_run(name, capsys):
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError as e:
        if (e.name or "").split(".")[0] in OPTIONAL:
            pytest.skip(f"{name} needs the optional {e.name}")
        raise
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    tests = [t for t in doctest.DocTestFinder().find(module, name) if t.examples]
    for t in tests:
        runner.run(t)
    failed, attempted = runner.summarize(verbose=False)
    report = capsys.readouterr().out
    assert failed == 0, report
