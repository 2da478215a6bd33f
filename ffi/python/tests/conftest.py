"""Fixtures of the Python bindings' tests: the CLI binary of the same workspace, run on the same
files, and the demo's synthetic test written once per session."""

import json
import os
import pathlib
import subprocess

import pytest

import volver

ROOT = pathlib.Path(__file__).resolve().parents[3]


def cli_binary():
    """The `volver` binary to compare with: $VOLVER_BIN, else the workspace's debug build (built
    when missing)."""
    given = os.environ.get("VOLVER_BIN")
    if given:
        return given
    path = ROOT / "target" / "debug" / "volver"
    if not path.exists():
        subprocess.run(
            ["cargo", "build", "-q", "--bin", "volver"], cwd=ROOT, check=True
        )
    return str(path)


def run_cli(*args, cwd=None):
    """Runs the CLI; returns its stdout (fails the test on a non-zero exit)."""
    out = subprocess.run(
        [cli_binary(), *map(str, args)], capture_output=True, text=True, cwd=cwd
    )
    assert out.returncode == 0, f"volver {' '.join(map(str, args))}: {out.stderr}"
    return out.stdout


def cli_json(*args):
    """The CLI's `--json` output, parsed."""
    return json.loads(run_cli(*args, "--json"))


@pytest.fixture(scope="session")
def demo(tmp_path_factory):
    """The demo's synthetic test 4 on the XCFZ grinder (seed 7, the 2nd harmonic of C hidden),
    written by the bindings: (folder, the simulation's record)."""
    folder = tmp_path_factory.mktemp("demo") / "test4"
    record = volver.demo_data(folder)
    return folder, record


@pytest.fixture(scope="session")
def fit(demo, tmp_path_factory):
    """The demo's data identified with the raise-axis:C model, the results file written by the
    bindings (fit.json, with its uncertainty record)."""
    folder, _ = demo
    out = tmp_path_factory.mktemp("fit") / "fit.json"
    result = volver.identify(folder / "measurements.csv", add=["raise-axis:C"], out=out)
    return out, result
