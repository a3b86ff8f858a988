"""A trajectory of particles in a triclinic periodic cell: frames per
second of cvd (each frame from the last one's neighbour lists, and each
frame rebuilt) against freud's Voronoi, on the same frames and threads.

    python3 bench/python/trajectory.py [--particles N] [--frames F]
        [--step S] [--block B] [--threads T]

The frames: N uniform particles at density 1 in LAMMPS's triclinic cell
(tilts xy = 0.2 L, xz = -0.1 L, yz = 0.15 L), then each frame the last
one moved by a normal step of S spacings along each axis (Brownian
particles; they cross the cell's sides, given unwrapped). Every tool runs
every frame in order, in blocks of B frames taken in turn (cvd reusing,
cvd rebuilding, freud, cvd reusing, ...), in one process with T threads
each. cvd computes each cell's volume, centroid and faces (neighbours,
areas, image shifts: what freud's nlist with weights holds); freud its
volumes, polytopes and nlist, its time including wrapping the frame into
its box. Prints frames per second per tool, the ratios, the cells cvd
built from the last frame's lists, and cvd's time per phase. Needs cvd
(the package) and freud.
"""

import argparse
import os
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--particles", type=int, default=32000)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--step", type=float, default=0.01)
    ap.add_argument("--block", type=int, default=50)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    os.environ["RAYON_NUM_THREADS"] = str(a.threads)
    import cvd
    import freud

    freud.parallel.set_num_threads(a.threads)
    n = a.particles
    rng = np.random.default_rng(0)
    L = n ** (1 / 3)
    A = np.array([[L, 0, 0], [0.2 * L, L, 0], [-0.1 * L, 0.15 * L, L]])
    frames = np.empty((a.frames, n, 3))
    frames[0] = rng.random((n, 3)) @ A
    for f in range(1, a.frames):
        frames[f] = frames[f - 1] + rng.normal(0.0, a.step, (n, 3))
    box = freud.box.Box.from_matrix(A.T)
    centre = 0.5 * A.sum(axis=0)
    voro = freud.locality.Voronoi()
    reuse = cvd.ParticleVoronoi(voronoi_index=False, faces=True, backend="cpu", reuse=True)
    rebuild = cvd.ParticleVoronoi(voronoi_index=False, faces=True, backend="cpu", reuse=False)
    tools = {
        "cvd, reusing lists": reuse,
        "cvd, every frame rebuilt": rebuild,
        "freud": None,
    }
    seconds = {t: 0.0 for t in tools}
    phases = {t: {} for t in tools}
    reused = 0
    worst = {t: 0.0 for t in tools}
    for start in range(0, a.frames, a.block):
        for name, tool in tools.items():
            t0 = time.perf_counter()
            for f in range(start, min(start + a.block, a.frames)):
                if tool is None:
                    pts = box.wrap((frames[f] - centre).astype(np.float32))
                    voro.compute((box, pts))
                    vol = voro.volumes
                else:
                    r = tool.compute(frames[f], A)
                    vol = r.volumes
                    for k, v in r.cells.timings.items():
                        phases[name][k] = phases[name].get(k, 0.0) + v
                    if tool is reuse:
                        reused += r.reused
                worst[name] = max(worst[name], abs(vol.sum() / np.linalg.det(A) - 1))
            seconds[name] += time.perf_counter() - t0
        done = min(start + a.block, a.frames)
        print(f"{done} frames: " + ", ".join(f"{t} {seconds[t]:.1f} s" for t in tools), flush=True)
    print(f"\n{n} particles, {a.frames} frames, steps of {a.step} spacings, {a.threads} threads")
    fps = {t: a.frames / s for t, s in seconds.items()}
    for t in tools:
        print(f"{t}: {seconds[t]:.1f} s, {fps[t]:.2f} frames/s, {fps[t] / fps['freud']:.2f}x freud; "
              f"volume error at most {worst[t]:.1e}")
    print(f"reusing against rebuilding: {fps['cvd, reusing lists'] / fps['cvd, every frame rebuilt']:.3f}x; "
          f"cells from the last frame's lists: {reused / (n * (a.frames - 1)):.1%} of frames 1..")
    for t in ("cvd, reusing lists", "cvd, every frame rebuilt"):
        print(f"{t}, per frame: " + ", ".join(f"{k} {1e3 * v / a.frames:.1f} ms" for k, v in phases[t].items()))


if __name__ == "__main__":
    main()
