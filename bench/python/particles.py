"""One frame of particles in a triclinic periodic cell: cvd against voro++
(pyvoro2's native call, one thread) and freud, side by side.

    python3 bench/python/particles.py [N ...] [--repeat R]

Each tool runs in a process of its own with RAYON_NUM_THREADS /
freud's thread count set, on the same points (uniform, density 1, LAMMPS
tilts xy = 0.2 L, xz = -0.1 L, yz = 0.15 L), alternating tools, R rounds;
prints each call's seconds and the best per tool, and cells per second per
thread. cvd's times are the whole call from Python (wrapping, images,
cells, and the arrays back); pyvoro2's skip its Python-side checks (the
native call on points wrapped into voro++'s domain); freud's include its
neighbour query. Needs cvd (the package), pyvoro2 and freud.
"""

import json
import os
import subprocess
import sys
import time

import numpy as np

RUN = r"""
import json, sys, time, numpy as np
tool, n, threads = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
rng = np.random.default_rng(0)
L = n ** (1 / 3)
A = np.array([[L, 0, 0], [0.2 * L, L, 0], [-0.1 * L, 0.15 * L, L]])
pos = rng.random((n, 3)) @ A
if tool.startswith("cvd"):
    import cvd
    faces = tool == "cvd-faces"
    t = time.perf_counter()
    r = cvd.particle_voronoi(pos, A, faces=faces, voronoi_index=False, backend="cpu")
    t = time.perf_counter() - t
    vol = r.volumes
elif tool == "voro++":
    import pyvoro2._core as core
    spacing = (np.linalg.det(A) / n) ** (1 / 3)
    nb = max(1, int(L / (2.5 * spacing)))
    pts = pos.copy()
    for ax, v in ((2, A[2]), (1, A[1]), (0, A[0])):
        pts -= np.floor(pts[:, ax] / v[ax])[:, None] * v
    t = time.perf_counter()
    cells = core.compute_periodic_standard(
        pts, np.arange(n, dtype=np.int32), (A[0, 0], A[1, 0], A[1, 1], A[2, 0], A[2, 1], A[2, 2]),
        (nb, nb, nb), 8, (False, False, False))
    t = time.perf_counter() - t
    vol = np.array([c["volume"] for c in cells])
else:
    import freud
    freud.parallel.set_num_threads(threads)
    box = freud.box.Box.from_matrix(A.T)
    t = time.perf_counter()
    pts = box.wrap((pos - 0.5 * A.sum(axis=0)).astype(np.float32))
    voro = freud.locality.Voronoi().compute((box, pts))
    vol = voro.volumes
    t = time.perf_counter() - t
print(json.dumps({"seconds": t, "volume_error": float(abs(vol.sum() / np.linalg.det(A) - 1))}))
"""


def once(tool, n, threads):
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    out = subprocess.run([sys.executable, "-c", RUN, tool, str(n), str(threads)], env=env, capture_output=True,
                         text=True, timeout=1800)
    if out.returncode != 0:
        raise RuntimeError(f"{tool} n={n}: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    args = sys.argv[1:]
    repeat = 3
    if "--repeat" in args:
        k = args.index("--repeat")
        repeat = int(args[k + 1])
        del args[k : k + 2]
    sizes = [int(a) for a in args] or [32000, 1000000]
    cores = os.cpu_count()
    runs = [("cvd", 1), ("cvd", cores), ("cvd-faces", cores), ("voro++", 1), ("freud", cores)]
    for n in sizes:
        times = {r: [] for r in runs}
        for _ in range(repeat):
            for tool, threads in runs:
                r = once(tool, n, threads)
                times[(tool, threads)].append(r["seconds"])
                print(f"n={n} {tool} x{threads}: {r['seconds']:.3f} s (volume sum off by {r['volume_error']:.1e})",
                      flush=True)
        print(f"\nn = {n}, best of {repeat}:")
        best = {r: min(t) for r, t in times.items()}
        for (tool, threads), t in best.items():
            print(f"  {tool:<10} {threads} thread(s) {t:8.3f} s  {n / t / threads:10.0f} cells/s per thread")
        voro = best[("voro++", 1)]
        print(f"  cvd per thread against voro++: {voro / best[('cvd', 1)]:.2f}x (1 thread), "
              f"{voro / (cores * best[('cvd', cores)]):.2f}x ({cores} threads, per thread)")
        print(f"  cvd against freud, {cores} threads: {best[('freud', cores)] / best[('cvd', cores)]:.2f}x\n")


if __name__ == "__main__":
    main()
