"""Two ways to test one shading point's segments against one candidate group, run by hand:

    python3 bench/bench_pair_streaming.py

`by segment` is what the occlusion map's kernel does (`accel.buffered_blocker`): each segment streams the
group's gathered rows with its own constants (shear, direction, end) in registers and leaves at its first
blocker. `by row` is the alternative of one pass over the rows for all of the pair's segments, each row tested
against every segment still unblocked (a blocked one is swapped out of the active list). Both give the same
values and the same counted tests (checked); reported per setting: seconds per counted test of each, and their
ratio. Synthetic rows: small triangles off the segments' bundle, and a share of blockers across it.
"""
import time

import numpy as np
from numba import njit

from probvis.accel import ray_setup
from probvis.accel.traversal import sheared_hit


@njit(cache=True, inline="always")
def _blocked(buf, w, kx, ky, kz, sx, sy, sz, tmax):
    return sheared_hit(buf[w, kx], buf[w, ky], buf[w, kz], buf[w, 3 + kx], buf[w, 3 + ky], buf[w, 3 + kz],
                       buf[w, 6 + kx], buf[w, 6 + ky], buf[w, 6 + kz], sx, sy, sz, 0.0, tmax)[0] < np.inf


@njit(cache=True, inline="always")
def _culled(cull, w, dx, dy, dz):
    c = cull[w, 0]
    return c != 0.0 and c * (cull[w, 1] * dx + cull[w, 2] * dy + cull[w, 3] * dz) <= 0.0


@njit(cache=True)
def by_segment(buf, cull, n_rows, dirs, perm, shear, reps, blocked, tests):
    for _ in range(reps):
        for k in range(dirs.shape[0]):
            dx, dy, dz = dirs[k, 0], dirs[k, 1], dirs[k, 2]
            kx, ky, kz = perm[k, 0], perm[k, 1], perm[k, 2]
            sx, sy, sz = shear[k, 0], shear[k, 1], shear[k, 2]
            blocked[k], tests[k] = False, 0
            for w in range(n_rows):
                if _culled(cull, w, dx, dy, dz):
                    continue
                tests[k] += 1
                if _blocked(buf, w, kx, ky, kz, sx, sy, sz, 1.0):
                    blocked[k] = True
                    break


@njit(cache=True)
def by_row(buf, cull, n_rows, dirs, perm, shear, reps, blocked, tests, active):
    n = dirs.shape[0]
    for _ in range(reps):
        for k in range(n):
            active[k], blocked[k], tests[k] = k, False, 0
        n_active = n
        for w in range(n_rows):
            a = 0
            while a < n_active:
                k = active[a]
                if _culled(cull, w, dirs[k, 0], dirs[k, 1], dirs[k, 2]):
                    a += 1
                    continue
                tests[k] += 1
                if _blocked(buf, w, perm[k, 0], perm[k, 1], perm[k, 2], shear[k, 0], shear[k, 1], shear[k, 2], 1.0):
                    blocked[k] = True
                    n_active -= 1
                    active[a] = active[n_active]
                else:
                    a += 1
            if n_active == 0:
                break


def main():
    rng = np.random.default_rng(0)
    n_seg = 48
    dirs = rng.normal(size=(n_seg, 3)) * 0.15 + np.array([0.2, 0.1, 1.0])
    perm = np.empty((n_seg, 3), np.int64)
    shear = np.empty((n_seg, 3))
    for k in range(n_seg):
        r = ray_setup(*dirs[k])
        perm[k], shear[k] = r[:3], r[3:]
    blocked1, blocked2 = np.empty(n_seg, np.bool_), np.empty(n_seg, np.bool_)
    tests1, tests2 = np.empty(n_seg, np.int64), np.empty(n_seg, np.int64)
    active = np.empty(n_seg, np.int64)
    print(f"{n_seg} segments from one point; seconds per counted test")
    for n_rows in (8, 20, 40, 80):
        for share in (0.0, 0.3):
            tv = rng.normal(size=(n_rows, 3, 3)) * 0.05 + np.array([2.0, 2.0, 0.5])
            for b in rng.choice(n_rows, int(share * n_rows), replace=False):
                tv[b] = np.array([0.1, 0.05, 0.5]) + rng.normal(size=3) * 0.05 + rng.normal(size=(3, 3)) * 0.06
            buf, cull = tv.reshape(n_rows, 9).copy(), np.zeros((n_rows, 4))
            reps = 400000 // n_rows
            by_segment(buf, cull, n_rows, dirs, perm, shear, 1, blocked1, tests1)
            by_row(buf, cull, n_rows, dirs, perm, shear, 1, blocked2, tests2, active)
            t0 = time.perf_counter()
            by_segment(buf, cull, n_rows, dirs, perm, shear, reps, blocked1, tests1)
            t1 = time.perf_counter()
            by_row(buf, cull, n_rows, dirs, perm, shear, reps, blocked2, tests2, active)
            t2 = time.perf_counter()
            assert (blocked1 == blocked2).all() and (tests1 == tests2).all()
            n_tests = reps * tests1.sum()
            print(f"rows {n_rows:3d}, blockers {share:.0%}, occluded {blocked1.mean():.2f}: by segment "
                  f"{(t1 - t0) / n_tests * 1e9:5.2f} ns, by row {(t2 - t1) / n_tests * 1e9:5.2f} ns, "
                  f"ratio {(t2 - t1) / (t1 - t0):.2f}", flush=True)


if __name__ == "__main__":
    main()
