"""The GIL is released while volver works, and the notebook-style example runs and prints the
demo's figures."""

import pathlib
import re
import subprocess
import sys
import threading

import volver
from conftest import run_cli

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "demo.py"


def test_another_thread_runs_while_volver_identifies(demo):
    """With a switch interval of an hour, a thread that holds the GIL is never made to give it
    up: the main thread runs during identify only if identify released it."""
    folder, _ = demo
    started, state = threading.Event(), {"finished": False}

    def work():
        started.set()
        volver.identify(folder / "measurements.csv")
        state["finished"] = True

    before = sys.getswitchinterval()
    sys.setswitchinterval(3600.0)
    try:
        worker = threading.Thread(target=work)
        worker.start()
        started.wait()
        ran_during = not state["finished"]
        worker.join()
    finally:
        sys.setswitchinterval(before)
    assert ran_during


def test_the_example_prints_the_demo_figures(tmp_path):
    """examples/demo.py reproduces steps 1–4 of `volver demo`: the same figures, as printed."""
    cli = run_cli("demo", "--out", tmp_path / "cli")
    out = subprocess.run(
        [sys.executable, str(EXAMPLE), str(tmp_path / "python")],
        capture_output=True, text=True, check=True,
    ).stdout
    wanted = [
        r"machine error EMM ([\d.]+) µm; noise error EMM ([\d.]+) µm",
        # (the iterations are identify's, which counts the gauge's last step: not compared)
        r"EMM ([\d.]+) → ([\d.]+) µm in",
        r"1\. (\S+)\s+ΔBIC\s+(-?[\d.]+)\s+EMM\s+([\d.]+) µm",
        r"2\. (\S+)\s+ΔBIC\s+(-?[\d.]+)\s+EMM\s+([\d.]+) µm",
        r"3\. (\S+)\s+ΔBIC\s+(-?[\d.]+)\s+EMM\s+([\d.]+) µm",
        r"Identification with (\S+): EMM ([\d.]+) µm \((\d+) parameters\) — ([\d.]+) × the noise error",
    ]
    for pattern in wanted:
        a, b = re.search(pattern, cli), re.search(pattern, out)
        assert a is not None, f"the CLI's demo has no {pattern}"
        assert b is not None, f"the example prints no {pattern}:\n{out}"
        assert a.groups() == b.groups(), pattern
