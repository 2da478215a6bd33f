"""volver's demo from Python, a notebook's cells in one script: a synthetic verification of the
XCFZ grinder whose data hide a 2nd harmonic of the turntable C, identified with the paper's
model, diagnosed, identified again with the missing effect, then its uncertainty, compensated
commands and the controller's error tables. Steps 1–4 print the figures `volver demo` prints
(the iteration count is `volver identify`'s: 11 here where the demo's own fit prints 10).

    python examples/demo.py [FOLDER]        (FOLDER: where the files go; volver-demo-py)
"""

import pathlib
import sys

import numpy as np

import volver

out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "volver-demo-py")
data_dir = out / "test4"

# %% 1. The simulated verification (seed 7, test 4, the paper's tracker noise).
record = volver.demo_data(data_dir)
data = data_dir / "measurements.csv"
noise_um = record["noise_error"]["emm_um"]
print(f"1. Simulated verification: plan test4 ({record['points']} points), seed 7")
print(
    f"   machine error EMM {record['machine_error']['emm_um']:.2f} µm; "
    f"noise error EMM {noise_um:.2f} µm (what a perfect model would leave)"
)

# %% 2. Identification with the paper's model (the embedded machine's default).
first = volver.identify(data)
print(
    f"\n2. Identification, paper model: EMM {first['emm_initial_um']:.2f} → "
    f"{first['emm_final_um']:.2f} µm in {first['iterations']} iterations"
)

# %% 3. Diagnosis: the residuals' periodogram over C and the candidates, best first.
diagnosis = volver.diagnose(data, top=3)
for p in diagnosis["periodograms"]:
    orders = ", ".join(
        f"order {line['order']:g}: {np.linalg.norm(line['amplitude_um']):.1f} µm"
        for line in p["lines"]
    )
    print(f"\n3. Diagnosis: periodogram of the residuals over {p['axis']} — {orders}")
for i, c in enumerate(diagnosis["candidates"], start=1):
    print(
        f"   {i}. {c['id']:<14} ΔBIC {c['delta_bic']:>8.1f}  EMM {c['emm_um']:>7.2f} µm  "
        f"{c['description']}"
    )
best = diagnosis["candidates"][0]["id"]

# %% 4. Identification with the missing effect; the results file (with its uncertainty).
fit_path = out / "fit.json"
second = volver.identify(data, add=[best], out=fit_path)
print(
    f"\n4. Identification with {best}: EMM {second['emm_final_um']:.2f} µm "
    f"({len(second['params'])} parameters) — {second['emm_final_um'] / noise_um:.3f} × the noise error"
)

# %% 5. The expanded uncertainty (k = 2) of the tool point over a grid of the volume.
u = volver.uncertainty(data, grid="X=0:1400:700,C=0:270:90,Z=0:600:300")
u95_um = max(max(p["u95_um"]) for p in u["points"])
print(f"\n5. Uncertainty: U95 of the tool point after the set-up's transform up to {u95_um:.2f} µm")

# %% 6. Compensated commands (X mm, C degrees, Z mm) and the controller's error tables.
commands = np.array([[100.0, 30.0, 50.0], [700.0, 200.0, 300.0]])
done = volver.compensate_points(fit_path, commands)
print(f"\n6. Compensation: uncompensated error up to {done['max_error_um']:.2f} µm at these points")
print("   " + done["csv"].replace("\n", "\n   ").rstrip())
tables = volver.tables(fit_path, out / "tables")
print(f"   tables written: {', '.join(pathlib.Path(f).name for f in tables['files'])}")
