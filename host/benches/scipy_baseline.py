#!/usr/bin/env python3
"""Baseline for docs/PERFORMANCE.md: scipy.optimize.least_squares on the same data as the
criterion benchmark (host/benches/fit.rs).

    python3 host/benches/scipy_baseline.py --write-data host/benches/data   # make the data
    python3 host/benches/scipy_baseline.py host/benches/data                # time scipy
    python3 host/benches/scipy_baseline.py host/benches/data --gonio target/release/gonio

The data: the eight Table 6 papers on 284 (full grid), 40 (dense around the peak) and 12
(Strategy 1, M = 12) geometries, 1 % relative + 0.003 absolute noise, seeded. The baseline:
method 'trf', the Table 3 bounds (sigma from 1e-3 deg, as in gonio), starts at
sigma in {0.3, 1, 3, 10, 30} deg (rho_s, rho_d from a linear fit at eta = 1.5), best of five.
With --gonio, the final costs of `gonio fit --acceptance 0` are compared on every data set.
Needs numpy and scipy; never a runtime dependency of gonio.
"""
import argparse
import csv
import json
import os
import subprocess
import sys
import time

import numpy as np
from scipy.optimize import least_squares

HERE = os.path.dirname(os.path.abspath(__file__))
TABLE6 = {
    "G": (0.8, 57.8, 0.855, 1.19),
    "SG": (1.9, 57.1, 0.795, 1.02),
    "PPC": (21.7, 0.409, 0.414, 3.0),
    "MC": (43.5, 0.123, 0.642, 3.0),
    "J1": (16.7, 0.734, 0.127, 3.0),
    "J2": (17.9, 0.729, 0.06, 3.0),
    "J3": (24.5, 0.404, 0.333, 3.0),
    "J4": (21.9, 0.469, 0.346, 3.0),
}
INCIDENCE = (20, 30, 45, 60)


def tsl(params, ti, tr):
    """The TSL radiance factor (METHOD.md), numpy, degrees."""
    sigma, rho_s, rho_d, eta = params
    ti_r, tr_r = np.radians(ti), np.radians(tr)
    psi = 0.5 * (ti_r + tr_r)
    theta_a = 0.5 * np.abs(ti - tr)
    s2, c = np.sin(psi) ** 2, np.cos(psi)
    r = np.sqrt(np.maximum(eta * eta - s2, 0.0))
    a = (eta * eta - 1.0) / (r + c) ** 2
    b = (c * r - s2) / (c * r + s2)
    fresnel = a * np.sqrt(1.0 + b * b)
    ci, cr, ca = np.cos(ti_r), np.cos(tr_r), np.cos(np.radians(theta_a))
    h = np.minimum(np.minimum(1.0 / (ci * cr), 2 * ca / (c * ci)), 2 * ca / (c * cr))
    return rho_s * fresnel * h * np.exp(-theta_a**2 / (2 * sigma**2)) + rho_d


def check_vectors():
    path = os.path.join(HERE, "..", "tests", "data", "tsl-vectors.csv")
    with open(path) as f:
        for row in csv.DictReader(f):
            p = [float(row[k]) for k in ("sigma_deg", "rho_s", "rho_d", "eta")]
            got = tsl(p, np.array([float(row["theta_i"])]), np.array([float(row["theta_r"])]))[0]
            want = float(row["radiance_factor"])
            assert abs(got - want) <= 1e-9 * abs(want), (row, got)


def schedules():
    full = [(ti, tr) for ti in INCIDENCE for tr in range(71)]
    dense = [(ti, tr) for ti in INCIDENCE for tr in sorted({0, ti - 10, ti - 6, ti - 3, ti - 1, ti, ti + 1, ti + 3, ti + 6, 70})]
    m12 = [(ti, tr) for ti in INCIDENCE for tr in (0, ti, 70)]
    return {"284": full, "40": dense, "12": m12}


def write_data(directory):
    os.makedirs(directory, exist_ok=True)
    rng = np.random.default_rng(20240601)
    for name, geometries in schedules().items():
        with open(os.path.join(directory, f"bench-{name}.csv"), "w") as f:
            f.write("sample,theta_i,theta_r,radiance_factor\n")
            for sample, p in TABLE6.items():
                g = np.array(geometries, dtype=float)
                clean = tsl(p, g[:, 0], g[:, 1])
                noisy = np.maximum(clean + rng.normal(size=clean.size) * np.hypot(0.01 * clean, 0.003), 0.0)
                for (ti, tr), y in zip(geometries, noisy):
                    f.write(f"{sample},{ti},{tr},{y:.10g}\n")


def read_data(path):
    sets = {}
    with open(path) as f:
        for row in csv.DictReader(f):
            sets.setdefault(row["sample"], []).append((float(row["theta_i"]), float(row["theta_r"]), float(row["radiance_factor"])))
    return {k: np.array(v) for k, v in sets.items()}


def scipy_fit(data):
    ti, tr, y = data[:, 0], data[:, 1], data[:, 2]
    lower, upper = [1e-3, 0.0, 0.0, 1.0], [90.0, np.inf, np.inf, 3.0]
    best = None
    for sigma0 in (0.3, 1.0, 3.0, 10.0, 30.0):
        g = tsl((sigma0, 1.0, 0.0, 1.5), ti, tr)
        design = np.column_stack([g, np.ones_like(g)])
        rho = np.maximum(np.linalg.lstsq(design, y, rcond=None)[0], 1e-6)
        x0 = [sigma0, rho[0], rho[1], 1.5]
        res = least_squares(lambda x: tsl(x, ti, tr) - y, x0, bounds=(lower, upper), method="trf")
        if best is None or res.cost < best.cost:
            best = res
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="?", default=os.path.join(HERE, "data"))
    ap.add_argument("--write-data", metavar="DIR")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--gonio", metavar="BINARY", help="compare final costs with this gonio binary")
    args = ap.parse_args()
    check_vectors()
    if args.write_data:
        write_data(args.write_data)
        return
    summary = {}
    for size in ("284", "40", "12"):
        path = os.path.join(args.data, f"bench-{size}.csv")
        sets = read_data(path)
        times, costs = [], {}
        for sample, data in sets.items():
            best_t = np.inf
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                res = scipy_fit(data)
                best_t = min(best_t, time.perf_counter() - t0)
            times.append(best_t)
            costs[sample] = 2 * res.cost  # scipy's cost is half the sum of squares
        print(f"n={size}: scipy least_squares (trf, 5 starts) median {1e3 * np.median(times):.2f} ms per fit "
              f"(min {1e3 * min(times):.2f}, max {1e3 * max(times):.2f})")
        summary[size] = {"median_ms": 1e3 * float(np.median(times)), "costs": costs}
        if args.gonio:
            out = subprocess.run([args.gonio, "fit", "--json", "--acceptance", "0", path], capture_output=True, text=True, check=False)
            ours = {json.loads(line)["sample"]: json.loads(line)["cost"] for line in out.stdout.splitlines()}
            for sample, c in costs.items():
                verdict = "lower/equal" if ours[sample] <= c * (1 + 1e-9) else "HIGHER"
                print(f"   {sample:4} cost scipy {c:.8e}  gonio {ours[sample]:.8e}  gonio {verdict}")
    json.dump(summary, sys.stderr)
    sys.stderr.write("\n")


if __name__ == "__main__":
    main()
