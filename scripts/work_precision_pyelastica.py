"""Work-precision of the rod against PyElastica at matched accuracy: wall time to reach a 10 %, 3 % and 1 % tip error.

Case: the benchmark cantilever of scripts/bench_pyelastica.py (L = 1 m, solid radius 1 cm, rho = 1000 kg/m^3,
E = 1e6 Pa, G = E/1.5, released from the first Euler-Bernoulli mode with a 1 cm tip deflection, no damping, 10 first
periods; tip error = max |y_tip(t) - 0.01 cos(omega_T t)| / 0.01, omega_T the Timoshenko first frequency of the
continuum).  PyElastica's error over 10 periods is set by its spatial resolution (its first frequency is +1.06 % off
at 100 elements), so it runs at 100-1600 elements, each at a safe fraction of its largest stable step (bisection on
3000-step runs, as scripts/bench_pyelastica.py); varint (Simulation: the planar model, midpoint, the compiled rod
step) at 50, 100 and 200 elements and 32-512 steps per period.

Timing: PyElastica's fastest honest use -- PositionVerlet.step in a plain loop, the tip read from
position_collection[1, -1] every k steps (about 500 samples per period), no energy in the timed loop; varint's
Simulation.step with the tip read from the state every step.  Each tool's cost per step is measured twice: the full
runs' wall times, and short alternating blocks (PyElastica 2000 steps, varint 200 steps, cheapest of 3) whose
per-step cost times the steps of the full run is a "quiet" wall time less disturbed by other processes.  PyElastica
runs whose estimated cost exceeds --max-minutes (default 25) are not run: their per-step cost is reported.

PyElastica is an optional comparison tool, not a dependency:  pip install -e '.[compare]'
Run:  python scripts/work_precision_pyelastica.py [--quick] [--max-minutes M]
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

from bench_pyelastica import TIP, largest_stable_dt, pyelastica_cantilever, reference, varint_cantilever  # noqa: E402
from varint.analysis.signals import zero_crossing_frequency  # noqa: E402

from varint import Simulation  # noqa: E402

E = 1e6
PERIODS = 10
TARGETS = (0.10, 0.03, 0.01)
SAMPLES_PER_PERIOD = 500  # PyElastica's tip samples (its steps per period are 10^5-10^6)


def least_time_to(rows, target, key="wall"):
    """The row of least rows[i][key] among those whose "error" is at most target (None if none reaches it)."""
    ok = [r for r in rows if r["error"] <= target and r.get(key) is not None]
    return min(ok, key=lambda r: r[key]) if ok else None


def tip_error(t, tip, w):
    return float(np.max(np.abs(tip - TIP * np.cos(w * t))) / TIP)


# ----------------------------------------------------------------------------- PyElastica


class PyElastica:
    """PositionVerlet on the cantilever at n_el elements and step dt, from the release."""

    def __init__(self, n_el, dt):
        import elastica as ea

        self.n_el, self.dt = n_el, dt
        self.sim, self.rod = pyelastica_cantilever(E, n_el)
        self.stepper = ea.PositionVerlet()
        self.t = 0.0

    def steps(self, n):
        sim, step, dt, t = self.sim, self.stepper.step, self.dt, self.t
        for _ in range(n):
            t = step(sim, t, dt)
        self.t = t

    def stable(self):
        p = self.rod.position_collection
        return bool(np.all(np.isfinite(p)) and np.max(np.abs(p[1])) < 0.1)


def pyelastica_full(n_el, dt, n, every):
    """n steps from the release, the tip sampled every `every` steps; (t, tip, wall of the stepping loop, stable)."""
    pe = PyElastica(n_el, dt)
    sim, step, rod = pe.sim, pe.stepper.step, pe.rod
    blocks, rest = divmod(n, every)
    ts, tips = np.empty(blocks + 1), np.empty(blocks + 1)
    ts[0], tips[0] = 0.0, rod.position_collection[1, -1]
    t = 0.0
    t0 = time.perf_counter()
    for b in range(blocks):
        for _ in range(every):
            t = step(sim, t, dt)
        ts[b + 1] = t
        tips[b + 1] = rod.position_collection[1, -1]
        if not abs(tips[b + 1]) < 0.1:  # blown up (or NaN): stop, the caller retries at a smaller step
            rest = 0
            break
    for _ in range(rest):
        t = step(sim, t, dt)
    wall = time.perf_counter() - t0
    pe.t = t
    return ts, tips, wall, pe.stable()


# ----------------------------------------------------------------------------- varint


class Varint:
    """The planar varint cantilever at n_el elements and k steps per first period T1, from the release."""

    def __init__(self, n_el, k, T1):
        self.n_el, self.k, self.h = n_el, k, T1 / k
        self.model = varint_cantilever(E, self.h, n_el)
        self.sim = Simulation(self.model)
        self.i_tip = self.model.rod_q.start + 3 * n_el + 1  # y of the tip node (planar layout: varint.model.model)

    def steps(self, n):
        sim = self.sim
        for _ in range(n):
            sim.step()


def varint_full(n_el, k, T1, n):
    v = Varint(n_el, k, T1)
    sim, i = v.sim, v.i_tip
    t, tip = np.empty(n + 1), np.empty(n + 1)
    t[0], tip[0] = 0.0, sim.state.q[i]
    t0 = time.perf_counter()
    for j in range(n):
        sim.step()
        t[j + 1] = sim.state.t
        tip[j + 1] = sim.state.q[i]
    wall = time.perf_counter() - t0
    return t, tip, wall, sim.stats.total_iterations / n


# ----------------------------------------------------------------------------- timing


def quiet_costs(pe_cfg, vi_cfg, T1, rounds=3, pe_block=2000, vi_block=200):
    """Cost per step of each configuration, cheapest of `rounds` alternating blocks (PyElastica pe_block steps,
    varint vi_block steps): every configuration sees the same load of the machine.  Each runs from the release,
    after a warm-up (compiled kernels, first Jacobian)."""
    runners = {("pe", n): PyElastica(n, dt) for n, dt in pe_cfg}
    runners.update({("vi", n, k): Varint(n, k, T1) for n, k in vi_cfg})
    for key, r in runners.items():
        r.steps(20 if key[0] == "vi" else 200)
    best = {key: math.inf for key in runners}
    for _ in range(rounds):
        for key, r in runners.items():
            m = pe_block if key[0] == "pe" else vi_block
            t0 = time.perf_counter()
            r.steps(m)
            best[key] = min(best[key], (time.perf_counter() - t0) / m)
    return best


# ----------------------------------------------------------------------------- report


def _ratio(a, b, rows_pe, key):
    """PyElastica's least time over varint's; if no PyElastica run reached the target, a lower bound: its error falls
    with the elements and its cost rises with them, so reaching the target costs more than its largest run done."""
    if a is None:
        return "—"
    if b is not None:
        return f"{b[key] / a[key]:.0f}"
    done = [r for r in rows_pe if r["wall"] is not None and r.get(key) is not None]
    if not done:
        return "—"
    top = max(done, key=lambda r: r["n_el"])
    return f"> {top[key] / a[key]:.0f} (> its {top['n_el']}-element run)"


def plot(rows_vi, rows_pe, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.6, 4.6), constrained_layout=True)
    for n_el, marker in ((50, "v-"), (100, "o-"), (200, "^-")):
        pts = sorted((r["wall"], r["error"]) for r in rows_vi if r["n_el"] == n_el)
        if pts:
            ax.loglog(*zip(*pts), marker, label=f"varint midpoint, {n_el} elements (32-512 steps/period)")
    pts = sorted((r["wall"], r["error"], r["n_el"]) for r in rows_pe if r["wall"] is not None)
    if pts:
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "s-", color="k", label="PyElastica PositionVerlet")
        for w, e, n_el in pts:
            ax.annotate(f"{n_el}", (w, e), textcoords="offset points", xytext=(5, 4), fontsize=8)
    for tgt in TARGETS:
        ax.axhline(tgt, color="0.6", lw=0.7, ls=":")
    ax.set_xlabel("wall time for 10 first periods [s]")
    ax.set_ylabel("tip error / amplitude over 10 periods")
    ax.set_title(f"cantilever, E = {E:.0e} Pa: varint vs PyElastica (elements labelled)", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=110)


def main(quick=False, max_minutes=25.0):
    w = reference(E)
    T1 = 2 * math.pi / w
    periods = 1 if quick else PERIODS
    pe_sizes = (20, 40) if quick else (100, 200, 400, 800, 1600)
    vi_sizes = (10, 20) if quick else (50, 100, 200)
    ks = (32, 64) if quick else (32, 64, 128, 181, 256, 362, 512)
    print(f"# cantilever, E = {E:.0e} Pa, T1 = {T1:.4g} s, {periods} first periods; "
          f"{'quick (smoke test)' if quick else 'full'} run, {time.strftime('%Y-%m-%d %H:%M')}\n", flush=True)

    # 1. PyElastica's largest stable step per resolution (bisection on 3000-step runs)
    dt_max = {}
    for n_el in pe_sizes:
        t0 = time.perf_counter()
        dt_max[n_el] = largest_stable_dt(E, w, n_el=n_el, steps=300 if quick else 3000)
        print(f"PyElastica {n_el} elements: largest stable dt {dt_max[n_el]:.4g} s (bisection {time.perf_counter() - t0:.0f} s)",
              flush=True)

    # 2. cost per step in alternating blocks, and the estimated cost of each full PyElastica run at 0.8 dt_max
    pe_cfg = [(n_el, 0.8 * dt_max[n_el]) for n_el in pe_sizes]
    vi_cfg = [(n_el, k) for n_el in vi_sizes for k in ks]
    quiet = quiet_costs(pe_cfg, vi_cfg, T1, pe_block=200 if quick else 2000, vi_block=20 if quick else 200)
    print("\n| PyElastica elements | dt_max [s] | run dt = 0.8 dt_max [s] | steps for the run | µs/step (quiet) | "
          "estimated wall [s] |")
    print("|---|---|---|---|---|---|")
    est = {}
    for n_el, dt in pe_cfg:
        n = int(round(periods * T1 / dt))
        est[n_el] = n * quiet[("pe", n_el)]
        print(f"| {n_el} | {dt_max[n_el]:.4g} | {dt:.4g} | {n} | {quiet[('pe', n_el)] * 1e6:.1f} | {est[n_el]:.0f} |")
    print(flush=True)

    # 3. varint's runs (cheap)
    rows_vi = []
    for n_el, k in vi_cfg:
        n = periods * k
        t, tip, wall, its = varint_full(n_el, k, T1, n)
        q = quiet[("vi", n_el, k)]
        rows_vi.append(dict(tool="varint", n_el=n_el, k=k, h=T1 / k, steps=n, wall=wall, us=wall / n * 1e6,
                            quiet_us=q * 1e6, quiet_wall=q * n, error=tip_error(t, tip, w), its=its,
                            freq=zero_crossing_frequency(t, tip) / w - 1))
    print("| varint elements | steps/period | h [s] | steps | wall [s] | µs/step | it./step | quiet µs/step | "
          "steps × quiet [s] | tip error | 1st freq. error |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows_vi:
        print(f"| {r['n_el']} | {r['k']} | {r['h']:.4g} | {r['steps']} | {r['wall']:.3f} | {r['us']:.1f} | "
              f"{r['its']:.2f} | {r['quiet_us']:.1f} | {r['quiet_wall']:.3f} | {r['error']:.2e} | {r['freq']:+.2e} |")
    print(flush=True)

    # 4. PyElastica's runs, cheapest first; a run estimated above max_minutes is not run
    rows_pe = []
    print("| PyElastica elements | dt [s] | fraction of dt_max | steps | wall [s] | µs/step | quiet µs/step | "
          "steps × quiet [s] | tip error | 1st freq. error |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n_el, dt in pe_cfg:
        q = quiet[("pe", n_el)]
        if est[n_el] > 60 * max_minutes:
            rows_pe.append(dict(tool="PyElastica", n_el=n_el, dt=dt, frac=None, steps=None, wall=None, us=None,
                                quiet_us=q * 1e6, quiet_wall=est[n_el], error=math.inf, freq=math.nan))
            print(f"| {n_el} | {dt:.4g} | not run: estimated {est[n_el] / 60:.0f} min | "
                  f"{int(round(periods * T1 / dt))} | | | {q * 1e6:.1f} | {est[n_el]:.0f} | | |", flush=True)
            continue
        for frac in (0.8, 0.5):
            dt = frac * dt_max[n_el]
            n = int(round(periods * T1 / dt))
            every = max(1, int(round(T1 / dt / SAMPLES_PER_PERIOD)))
            t, tip, wall, stable = pyelastica_full(n_el, dt, n, every)
            if stable:
                break
            print(f"| {n_el} | {dt:.4g} | {frac} | {n} | {wall:.1f} | unstable: retried at 0.5 dt_max | | | | |")
        r = dict(tool="PyElastica", n_el=n_el, dt=dt, frac=frac, steps=n, wall=wall, us=wall / n * 1e6,
                 quiet_us=q * 1e6 if frac == 0.8 else None, quiet_wall=q * n if frac == 0.8 else None,
                 error=tip_error(t, tip, w) if stable else math.inf,
                 freq=zero_crossing_frequency(t, tip) / w - 1 if stable else math.nan)
        rows_pe.append(r)
        qs = f"{r['quiet_us']:.1f} | {r['quiet_wall']:.1f}" if r["quiet_us"] is not None else " | "
        print(f"| {n_el} | {dt:.4g} | {frac} | {n} | {wall:.1f} | {r['us']:.1f} | {qs} | {r['error']:.2e} | "
              f"{r['freq']:+.2e} |", flush=True)
    print()

    # 5. least wall time to each target, and the ratio
    print("| target | varint: least wall [s] (run) | PyElastica: least wall [s] (run) | ratio | "
          "varint steps × quiet [s] | PyElastica steps × quiet [s] | ratio |")
    print("|---|---|---|---|---|---|---|")
    for tgt in TARGETS:
        cells = []
        for key in ("wall", "quiet_wall"):
            a, b = least_time_to(rows_vi, tgt, key), least_time_to(rows_pe, tgt, key)
            cells.append((a, b))
        (a, b), (qa, qb) = cells

        def run(r, key, name):
            if r is None:
                return "not reached"
            label = f"{r['n_el']} el., {r['k']}/period" if name == "vi" else f"{r['n_el']} el."
            return f"{r[key]:.3g} ({label})"

        ratio, qratio = _ratio(a, b, rows_pe, "wall"), _ratio(qa, qb, rows_pe, "quiet_wall")
        print(f"| {tgt:.0%} | {run(a, 'wall', 'vi')} | {run(b, 'wall', 'pe')} | {ratio} | "
              f"{run(qa, 'quiet_wall', 'vi')} | {run(qb, 'quiet_wall', 'pe')} | {qratio} |")
    plot(rows_vi, rows_pe, Path("/tmp/rod_work_precision_matched_quick.png") if quick
         else ROOT / "docs" / "rod_work_precision_matched.png")
    return rows_vi, rows_pe


if __name__ == "__main__":
    mm = float(sys.argv[sys.argv.index("--max-minutes") + 1]) if "--max-minutes" in sys.argv else 25.0
    main(quick="--quick" in sys.argv, max_minutes=mm)
