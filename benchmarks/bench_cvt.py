"""Benchmark of the spherical CVT solvers, plus the paper's geometric figures.

Run from the repository root::

    python benchmarks/bench_cvt.py            # everything (plain Lloyd at n = 1000 takes ~1 min)
    python benchmarks/bench_cvt.py --quick    # skip plain Lloyd at n = 1000
    python benchmarks/bench_cvt.py --sections 0                 # fast path vs today's solver
    python benchmarks/bench_cvt.py --sections 0 --profile 1000  # + cProfile of both

Prints:

0. the default ``cvt_sphere(n)`` fast path (``method="fast"`` from n = 500) against the
   previous default (``method="lbfgs"``, random start, ``ConvexHull`` per evaluation) in the
   same run: process CPU time (best of ``--repeat`` for the fast path, one run of the plain one),
   evaluations, energy and d_min and their relative differences (targets: n = 1000 < 0.3 s,
   n = 10 000 < 10 s, energy and d_min within 1 %). Section 0 uses CPU time
   (``time.process_time``), not wall time: the machine is shared, so wall time measures the
   neighbours; CPU time is still inflated by them (caches, hyper-threads), hence best of N;
1. fast solver (L-BFGS) vs plain exact Lloyd, both to a 1e-10 Lloyd move: wall and CPU time,
   iterations, exact Voronoi evaluations, energy and relative energy difference (targets:
   n = 200 under 0.3 s, n = 1000 under 3 s);
2. the paper's mesh Lloyd vs the exact CVT (energy gap);
3. asynchronous distributed Lloyd vs central Lloyd (energy);
4. Table I (d_min) and the footnote figures (r_bar, ||M_alpha||, ||(N D^2/3) M^-1||), N = 4..30;
5. reconfiguration after a loss: travel with/without warm start and rotation.

Wall times depend on the machine's load (other jobs): the CPU (process) time is printed beside
them; for the fast solver the best of ``--repeat`` runs is shown.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import math
import pstats
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from formation import (  # noqa: E402
    assign_slots,
    cvt_energy,
    cvt_sphere,
    cvt_from,
    cvt_sphere_result,
    distributed_lloyd,
    lloyd_mesh_result,
    metrics,
    random_sphere_points,
    reconfigure,
    symmetric_cylinder,
    symmetric_cylinder_dmin,
)
from formation.symmetric import THETA_F_RAD  # noqa: E402


def _timed(fn, *args, **kwargs):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - w0, time.process_time() - c0


def _cpu_best(fn, repeat):
    best = None
    for _ in range(repeat):
        c0 = time.process_time()
        out = fn()
        cpu = time.process_time() - c0
        best = (out, cpu) if best is None or cpu < best[1] else best
    return best


def _profile(fn, top=8):
    prof = cProfile.Profile()
    prof.runcall(fn)
    out = io.StringIO()
    pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(top)
    lines = [ln for ln in out.getvalue().splitlines() if ln.strip()]
    print("\n".join(lines[2:]))


def bench_fast_path(sizes, repeat, plain_max, profile_n):
    print("== 0. cvt_sphere fast path vs today's plain L-BFGS (seed 0, tol 1e-10, CPU s) ==")
    print(f"{'n':>6} {'method':>6} {'cpu_s':>8} {'evals':>6} {'energy':>18} {'d_min':>9} "
          f"{'rel_E':>9} {'rel_dmin':>9}")
    for n in sizes:
        fast, cpu_f = _cpu_best(lambda n=n: cvt_sphere_result(n, seed=0, method="fast"), repeat)
        rows = [("fast", fast, cpu_f)]
        if n <= plain_max:
            plain, cpu_p = _cpu_best(lambda n=n: cvt_sphere_result(n, seed=0, method="lbfgs"), 1)
            rows.insert(0, ("lbfgs", plain, cpu_p))
        ref = rows[0][1] if n <= plain_max else None
        for name, res, cpu in rows:
            d_min = metrics(res.points).d_min
            rel_e = f"{res.energy / ref.energy - 1:+.2e}" if ref else "n/a"
            rel_d = f"{d_min / metrics(ref.points).d_min - 1:+.2e}" if ref else "n/a"
            flag = "" if res.converged else " NOT CONVERGED"
            print(f"{n:>6} {name:>6} {cpu:8.3f} {res.evaluations:6d} {res.energy:18.14f} "
                  f"{d_min:9.6f} {rel_e:>9} {rel_d:>9}{flag}")
    if profile_n:
        for name in ("lbfgs", "fast"):
            print(f"-- cProfile, cvt_sphere({profile_n}, method={name!r}), top by own time --")
            _profile(lambda name=name: cvt_sphere(profile_n, method=name))
    print("(rel_*: fast against lbfgs; d_min higher / energy lower is better. The default\n"
          " method='auto' is 'fast' from n = 500 and exactly 'lbfgs' below.)\n")


def bench_solvers(sizes, repeat, skip_lloyd_above):
    print("== 1. exact CVT: L-BFGS vs plain Lloyd (tol = 1e-10 Lloyd move, seed 0) ==")
    head = (f"{'n':>5} {'method':>12} {'wall_s':>8} {'cpu_s':>8} {'iters':>7} {'evals':>7} "
            f"{'energy':>20} {'rel_dE_vs_lloyd':>16}")
    print(head)
    for n in sizes:
        rows = {}
        for method in ("lbfgs", "lbfgs-scipy"):
            best = None
            for _ in range(repeat if method == "lbfgs" else 1):
                res, wall, cpu = _timed(cvt_sphere_result, n, seed=0, method=method)
                if best is None or wall < best[1]:
                    best = (res, wall, cpu)
            rows[method] = best
        if n <= skip_lloyd_above:
            rows["lloyd"] = _timed(cvt_sphere_result, n, seed=0, method="lloyd")
        ref = rows["lloyd"][0].energy if "lloyd" in rows else None
        for method, (res, wall, cpu) in rows.items():
            rel = f"{res.energy / ref - 1.0:+.2e}" if ref else "n/a"
            flag = "" if res.converged else " NOT CONVERGED"
            print(f"{n:>5} {method:>12} {wall:8.3f} {cpu:8.3f} {res.iterations:7d} "
                  f"{res.evaluations:7d} {res.energy:20.15f} {rel:>16}{flag}")
    print("(rel_dE != 0 beyond ~1e-14 means the solvers ended in different local minima of the\n"
          " CVT energy, which has many for large n; neither is then 'wrong'.)\n")


def bench_mesh(cases):
    print("== 2. paper's mesh Lloyd (Fibonacci mesh) vs exact CVT ==")
    print(f"{'n':>4} {'mesh':>7} {'iters':>6} {'wall_s':>7} {'E_exact(mesh result)':>21} "
          f"{'E_exact(polished)':>18} {'gap':>10} {'max_dist':>9}")
    for n, m in cases:
        res, wall, _ = _timed(lloyd_mesh_result, n, mesh_points=m)
        polished = cvt_from(res.points, method="lbfgs")  # exact CVT in the same basin
        gap = cvt_energy(res.points) / polished.energy - 1.0
        dist = max(float(x) for x in ((res.points - polished.points) ** 2).sum(1) ** 0.5)
        print(f"{n:>4} {m:>7} {res.iterations:>6} {wall:7.2f} {cvt_energy(res.points):21.12f} "
              f"{polished.energy:18.12f} {gap:10.2e} {dist:9.2e}")
    print("(gap: relative excess of the exact energy of the mesh result over the exact CVT\n"
          " reached from it; max_dist: largest generator displacement between the two.)\n")


def bench_distributed(sizes):
    print("== 3. asynchronous distributed Lloyd vs central Lloyd (same start, tol 1e-10) ==")
    print(f"{'n':>4} {'rounds':>7} {'updates':>8} {'wall_s':>7} {'E_distributed':>20} "
          f"{'E_central':>20} {'rel_dE':>10} {'central_move':>13}")
    for n in sizes:
        start = random_sphere_points(n, 0)
        dist, wall, _ = _timed(distributed_lloyd, start, seed=1, tol=1e-10)
        central = cvt_from(start, method="lloyd")
        move = cvt_from(dist.points, method="lloyd", max_iter=1).max_move
        print(f"{n:>4} {dist.rounds:>7} {dist.updates:>8} {wall:7.2f} {dist.energy:20.15f} "
              f"{central.energy:20.15f} {dist.energy / central.energy - 1:10.2e} {move:13.2e}")
    print("(central_move: how far one central exact Lloyd step moves the distributed result,\n"
          " i.e. it is a CVT of the whole sphere; rel_dE != 0: another local minimum.)\n")


def bench_reconfigure(sizes, radius_m=4.0):
    print(f"== 5. reconfiguration after losing vehicle 0 (CVT formation, D = {radius_m} m) ==")
    print(f"{'n':>4} {'variant':>28} {'wall_s':>7} {'max_travel_m':>13} {'rms_travel_m':>13} "
          f"{'sum_sq_m2':>10}")
    for n in sizes:
        current = cvt_sphere_result(n, seed=0).points * radius_m
        rec, wall, _ = _timed(reconfigure, current, 0, radius_m)
        xs = current[rec.survivors]
        fresh = cvt_sphere_result(n - 1, seed=0).points * radius_m
        rows = [("warm start + rotation", wall, rec.slots[rec.assignment] - xs)]
        perm, _ = assign_slots(xs, rec.cvt.points * radius_m)
        rows.append(("warm start, no rotation", wall, rec.cvt.points[perm] * radius_m - xs))
        perm, _ = assign_slots(xs, fresh)
        rows.append(("fresh CVT seed 0, no rotation", float("nan"), fresh[perm] - xs))
        perm, rot = assign_slots(xs, fresh, allow_rotation=True)
        rows.append(("fresh CVT seed 0 + rotation", float("nan"), rot[perm] - xs))
        for name, w, d in rows:
            t = (d**2).sum(1) ** 0.5
            print(f"{n:>4} {name:>28} {w:7.3f} {t.max():13.3f} {(t**2).mean() ** 0.5:13.3f} "
                  f"{(t**2).sum():10.3f}")
    print()


def paper_figures(n_starts):
    print("== 4a. Table I: d_min, D = 1 ==")
    print(f"{'N':>3} {'sym (positions)':>16} {'sym closed form':>16} {'paper formula':>14} "
          f"{'paper':>6} {'CVT seed0':>10} {f'CVT best/{n_starts}':>12} {'paper':>6}")
    paper_sym = {6: 1.00, 8: 0.81, 10: 0.68, 20: 0.37}
    paper_cvt = {6: 1.41, 8: 1.14, 10: 1.06, 20: 0.76}
    for n in (6, 8, 10, 20):
        sym = metrics(symmetric_cylinder(n)).d_min
        formula = 2.0 * math.cos(THETA_F_RAD) * math.sin(2.0 * math.pi / n)
        cvt0 = metrics(cvt_sphere_result(n, seed=0).points).d_min
        cvtb = metrics(cvt_sphere_result(n, seed=0, n_starts=n_starts).points).d_min
        print(f"{n:>3} {sym:16.4f} {symmetric_cylinder_dmin(n):16.4f} {formula:14.4f} "
              f"{paper_sym[n]:6.2f} {cvt0:10.4f} {cvtb:12.4f} {paper_cvt[n]:6.2f}")
    print("\n== 4b. footnotes, CVT formation, D = 1 (lowest energy of "
          f"{n_starts} seeds; paper: |r_bar| ~ 1e-4, ||M_a|| <= 0.3, ||.|| <= 1.04) ==")
    print(f"{'N':>3} {'energy':>14} {'|r_bar|':>10} {'||M_alpha||':>12} "
          f"{'||(N/3)M^-1||':>14} {'cond(M)':>8} {'d_min':>7}")
    for n in range(4, 31):
        res = cvt_sphere_result(n, seed=0, n_starts=n_starts)
        m = metrics(res.points)
        print(f"{n:>3} {res.energy:14.10f} {m.r_bar_norm:10.2e} {m.norm_M_alpha:12.4f} "
              f"{m.norm_scaled_Minv:14.4f} {m.cond_M:8.4f} {m.d_min:7.4f}")
    print()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="skip plain Lloyd for n > 500")
    parser.add_argument("--repeat", type=int, default=3, help="runs of the fast solver (best)")
    parser.add_argument("--starts", type=int, default=10, help="seeds tried for section 4")
    parser.add_argument("--sections", default="012345", help="which sections to run, e.g. 14")
    parser.add_argument("--fast-sizes", default="1000,10000", help="n of section 0")
    parser.add_argument("--plain-max", type=int, default=10000,
                        help="largest n solved by the plain solver in section 0 (n = 10 000: ~1 min)")
    parser.add_argument("--profile", type=int, default=0, help="cProfile both solvers at this n")
    args = parser.parse_args(argv)
    if "0" in args.sections:
        sizes = [int(x) for x in args.fast_sizes.split(",")]
        bench_fast_path(sizes, args.repeat, args.plain_max, args.profile)
    if "1" in args.sections:
        bench_solvers((50, 200, 500, 1000), args.repeat, 500 if args.quick else 10**9)
    if "2" in args.sections:
        bench_mesh([(8, 5000), (8, 20000), (10, 5000), (10, 20000), (20, 20000), (30, 20000),
                    (200, 20000), (200, 100000)])
    if "3" in args.sections:
        bench_distributed((8, 12, 20, 30))
    if "4" in args.sections:
        paper_figures(args.starts)
    if "5" in args.sections:
        bench_reconfigure((6, 8, 12, 30, 100))
    return 0


if __name__ == "__main__":
    sys.exit(main())
