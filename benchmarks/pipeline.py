"""Benchmark: runtime of the mapping stages against the ray tracing they feed, on one synthetic corner.

``holodata.synth.synthesize`` one corner (default a 400-cycle L corner: 400 radar cycles at 2 Hz =
200 s; the robot drives ~3.5 m and then stands; LiDAR ``--lidar`` at 10 Hz, of which ingest keeps
the scan nearest each radar frame, so slam sees 400 scans; LiDAR and camera at synth's defaults,
64x1024 and 376x672, since 2026-12-02 — the tables below that date used 64x512 and a 94x168
camera, which flatters register: ``--lidar 64x512 --camera 94x168`` repeats them), then times, each
in seconds:

* ``ingest`` (``holodata.ingest.ingest``; radar grid ``--radar-grid`` — small, to keep synth fast);
* ``slam`` (``holodata.mapping.slam.slam_scene``: kiss-icp + scan-to-map refinement + static mesh);
* ``register`` (``holodata.mapping.register.register_scene``: LiDAR segmentation, camera extrinsic,
  human surfaces; its own phases are printed);
* ``raytrace-gt`` of the same corner through the SLAM mesh, radar poses and register's human surfaces,
  ``GTConfig()`` (64x512 beams, 3 bounces): the work of ``holodata raytrace-gt DATASET`` at the paper's
  beam grid (until 2026-12-02 the mesh alone, as ``benchmarks/slam.py --raytrace`` does: 6.7 s
  instead of 9.8-10.4 s on the default corner, so the ratios above that date are ~1.5x too high);

and prints (slam + register) / raytrace-gt as a ratio (issue 9: it must not dominate; aim < 1) and
slam + register's share of the four stages' wall time, with the load average before and after (2
shared cores: compare ratios from the same run). slam's ATE
and mesh F@5cm against ``truth/`` are printed too, so a speed-up that costs accuracy shows.

``--gt-diff`` also ray-traces the *true* mesh (``truth/mesh.ply``, people removed) at the true radar
poses and prints, per bounce, the median |range(SLAM-mesh GT) - range(truth-mesh GT)| over beams
valid in both (cm).

Measured 2026-12-01, 400-cycle L corner (seed 1, 64x512 LiDAR, camera 94x168), 2 cores shared with
other helpers' jobs at load 13-15 (wall seconds inflated ~3x; CPU seconds are this process and its
workers only):

    stage            wall s    CPU s
    ingest             14.4      6.7
    slam               38.8     12.9    (ATE 0.24 cm, F@5cm 0.994; 366 of 400 scans at rest)
    register           71.1     40.5    (segment 26.7, map 18.4, extrinsic 2.8, humans 22.2 s wall)
    raytrace-gt        29.0     16.8
    slam+register     110.0     53.5    = 3.79x raytrace-gt wall, 3.19x its CPU (slam alone 0.77x CPU)

Rerun idle (load ~1.1, after the reader's sequential ragged reads, register's map cap and its
int64-key unique rows; `--keep /tmp/sp/p400 --reuse`):

    stage            wall s    CPU s
    ingest              4.2      7.1
    slam               11.2     12.9    (ATE 0.24 cm, F@5cm 0.994)
    register           26.6     27.8    (segment 17.6, map 2.6, extrinsic 1.3, humans 4.6 s wall)
    raytrace-gt         9.7     18.5    (2 worker processes)
    slam+register      37.8     40.7    = 3.88x raytrace-gt wall, 2.21x its CPU (slam alone 1.15x wall, 0.70x CPU)

register's segmentation (background model + per-scan segmentation, each pass reading and
deskewing every scan) was then the largest part.

After the segmentation speed-up (``holodata.mapping.segment``: dense voxel grid for the background
model's occupancy count and lookups, ``lidar/range`` read a shard at a time, one transform per scan
at rest / one pose per column while moving, and ``background_and_segment``: the segmentation reuses
the background pass's world points, so the scans without foreground — most of the 366 at rest — are
read once; "after" with ``register_scene`` calling ``background_and_segment``), the same corner
before / after in the same conditions (2 shared cores at load 6-7, ``--keep DIR --reuse``, one run
after the other; lidar/instance and the SLAM mesh identical; ingest's difference is load noise):

    stage            before wall / CPU s     after wall / CPU s
    ingest               19.9 / 11.3             11.5 /  7.4
    slam                 19.6 / 12.5             17.1 / 12.2   (slam's background model is the same code)
    register             35.2 / 24.1             19.6 / 12.8   (segment 22.7 -> 5.8 s wall)
    raytrace-gt          27.0 / 18.0             27.8 / 17.3
    slam+register        54.8 / 36.6             36.6 / 25.0   = 2.03x -> 1.32x raytrace-gt wall, 2.03x -> 1.44x its CPU

A second pair with the final code (``LidarScans.scan_world`` for the background pass), load 3.1-4.7:
register 30.2 / 29.0 -> 13.6 / 12.9 s wall / CPU (segment phase 21.0 -> 4.8 s), slam+register 45.5 ->
32.0 s = 2.04x -> 1.75x raytrace-gt wall (raytrace-gt 22.4 and 18.3 s: it varies with the load).
Background + segmentation alone on this corner's dataset (same masks; ``background_and_segment``
vs ``build_background`` + ``segment_scene``), load 3.8-5.3: 20.7-22.5 s wall, 16.9-18.1 s CPU before,
4.2-4.5 s wall and CPU after. register's other phases (map ~2 s, extrinsic 1-3 s, humans ~5 s at this
load) and slam are now most of slam+register; it is still above raytrace-gt (aim: below).

Before the slam speed-up (same corner, load 10-15) slam took 51.8 s wall next to raytrace-gt 44.8 s and
register 101.7 s. register now dominates: its LiDAR scans are read frame by frame three times
(background, segmentation, map; zarr waits), trajectories interpolated per scan, open3d voxel
downsampling per scan, the floor plane fit and the per-frame closed human surfaces.
``--gt-diff`` on this corner (true radar poses): median |range(SLAM-mesh GT) - range(true-mesh GT)|
bounce 1/2/3 0.3/0.4/0.4 cm (p90 1.1/2.2/5.9 cm) with the plane snapping of the SLAM mesh,
0.4/8.4/31.8 cm (p90 1.4/74.8/202.7 cm) without.

After slam's beam-by-beam rest check (``slam._SameBeam``; ``--keep DIR --reuse --gt-diff``, load
2.7-3.5, register as committed then):

    stage            wall s    CPU s
    ingest              7.8      7.1
    slam               10.7     10.1    (ATE 0.28 cm, F@5cm 0.994; 373 scans at rest, 339 decided beam by beam)
    register           13.6     14.2    (segment 4.1, map 1.1, extrinsic 4.8, humans 3.2 s wall)
    raytrace-gt         8.3     15.8
    slam+register      24.3     24.3    = 2.91x raytrace-gt wall, 1.54x its CPU (slam alone 1.28x wall, 0.64x CPU)

slam alone on this corner's ingested dataset, old and new code alternated five times (load 2.4-5.5):
13.4 -> 11.1 s wall, 12.2 -> 10.1 s CPU (means). ``--gt-diff``: bounce 1/2/3 median 0.3/0.4/0.5 cm,
p90 1.1/2.2/6.2 cm (before: 0.3/0.4/0.4, p90 1.1/2.2/5.9 cm; a few rest scans are held now instead of
re-registered, ATE 0.24 -> 0.28 cm; ``SlamConfig(same_beam=False)`` gives the old poses and mesh).

End of the stop (register's target denoising with its chunked neighbour search, idle, load 1.0-2.0):

    stage            wall s    CPU s
    ingest              4.2      7.1
    slam                9.4     10.8
    register           14.9     16.2    (segment 5.8, map 1.6, extrinsic 3.0, humans 4.1 s wall)
    raytrace-gt         9.5     17.9
    slam+register      24.3     27.0    = 2.56x raytrace-gt wall, 1.51x its CPU (slam alone 0.99x wall, 0.60x CPU)

slam and register each run on one core, raytrace-gt on both: the aim (below raytrace-gt) needs
register's per-scan / per-frame loops on both cores.

2026-12-01 evening, both on two cores (register: the LiDAR half in a forked process beside the camera
half, the map handed over before the segmentation, camera/points_world and half the surfaces in a
second process; map from the background pass's points; slam: scans read in a thread, the mesh's
background model in a forked process). Idle (load 0.7-1.3); this evening the same code ran ~15 %
slower than at the end of the last stop (ingest 4.2 -> 5.7-7.7 s, raytrace-gt 9.5 -> 10.2-10.4 s):

    stage            wall s    CPU s
    ingest              5.7      8.1
    slam               11.2     14.4    (read 2.5 s in a thread, refine 3.1, mesh 5.2)
    register           10.6     14.5    (camera 0.9, wait for the map 4.4, extrinsic 2.3, humans 2.1 s wall)
    raytrace-gt        10.2     19.1
    slam+register      21.8     28.9    = 2.15x raytrace-gt wall, 1.51x its CPU (a second run: 23.0 s, 2.22x)

The old code in the same conditions (a worktree at 53e5261, each stage alone, alternated twice):
slam 11.2-12.3 s vs 10.8-11.7 s now; register 15.4 s vs 13.4-14.0 s now (these include imports).
Now register's critical path is the LiDAR process's background model and map (~5.5 s: reading and
de-skewing 400 scans, the free-space test, the centroids), then the extrinsic (local plane
projection of the map near the camera, 1.7 s) and the humans; slam's is its refinement and Poisson
(2.4 s, single-threaded, holds the GIL). Splitting the background pass, the segmentation or slam's
scan reading over two processes gained nothing measurable (copy-on-write faults, pickling).

2026-12-02, idle (load 1.0-1.7), after slam stores its static point map (``map/points``) and register
registers onto it instead of building its own (its LiDAR process only builds the background model and
segments), with BLAS-free ``transform_points``, and the human solid model; raytrace-gt with humans:

    stage            wall s    CPU s
    ingest          3.2-3.3   5.0-5.2
    slam            6.8-7.3   8.7-9.5   (read 1.6 s in a thread, kiss-icp 0.5, refine 1.9, mesh 3.3-3.7)
    register        4.6       7.6-7.8   (camera 0.3-0.4, extrinsic 1.5, humans 2.1-2.2 | LiDAR process:
                                         background 2.3-2.7, segment 0.7-0.8 s)
    raytrace-gt     9.9-10.1 18.9-19.2
    slam+register  11.4-11.9 16.6-17.0  = 1.15-1.18x raytrace-gt wall, 0.88-0.89x its CPU; 47 % of the four
                                          stages' wall time; raytrace-gt is the largest stage

The code before (a worktree at c3791e1) alternated with this one on the same recording, three pairs
(raytrace-gt then without humans, 7.7-9.9 s): slam+register 13.6-16.0 s old vs 11.1-15.7 s new (the
first pair ran on a cold page cache: 15.3 vs 15.7), register 6.9-7.9 vs 4.1-5.5 s (the map's wait,
2.8-3.4 s, is gone), slam unchanged within the noise (6.7-8.1 vs 7.0-10.2 s).
Where the rest is: slam's Poisson (1.7 s, single-threaded) and point accumulation (1.3 s), register's
two halves are each ~3.5-4 s of CPU on the two cores.

The same day at synth's default sizes (64x1024 LiDAR, 376x672 camera; load 1.4-2.3, `--keep DIR`):
with ``camera/points_world`` still written by default (a 64x512 LiDAR) register took 18.2 s (camera
4.0, extrinsic 1.8, humans 11.8 s: the humans phase waited for the forked writer of that 0.9 GB copy,
which re-reads every camera frame), slam+register 2.47x raytrace-gt. With the copy on request only
(``register --camera-world``):

    stage            wall s    CPU s
    ingest             14.3     23.1
    slam               10.9     14.6    (ATE 0.19 cm, F@5cm 0.997; read 2.9 s, refine 3.2, mesh 6.1)
    register           14.9     24.8    (camera 7.3, extrinsic 2.4, humans 4.5 | LiDAR process:
                                         background 6.7, segment 1.7 s)
    raytrace-gt        11.3     20.8
    slam+register      25.7     39.4    = 2.28x raytrace-gt wall, 1.89x its CPU; 50 % of the pipeline;
                                          register is the largest stage

Then with register's depth images made one frame at a time (the static depth from 60 frames first,
so the extrinsic starts while the LiDAR process still works), two runs (`--keep DIR [--reuse]`,
load 1.3-2.0): slam 8.7 / 9.9, register 9.9 / 11.3 (camera 1.7-2.6, extrinsic 2.1-2.3, humans 5.7-5.9
| background 4.8-5.7, segment 1.2-1.3), raytrace-gt 10.7 / 11.4 s: slam+register 18.7 / 21.2 s =
1.74x / 1.86x raytrace-gt wall, 1.45x / 1.51x its CPU, 46-47 % of the pipeline; the largest stage
raytrace-gt / ingest. register alone on that corner, old and new alternated: 13.6 / 11.3 -> 11.3 /
10.4 s, max RSS 0.95 -> 0.62 GB.
So at the recording sizes synth writes the aim is still far off: register's two halves each keep a core
busy (the camera half reads and projects 100 M camera points, 2.5-6 ms a frame, and builds the
static depth; the LiDAR half builds its own background model from 26 M LiDAR points, which slam
has already built once for its mesh from a subset of the same scans).

2026-12-02 ~04:25 UTC after the synth heading fix (a new recording) and register's reused depth
images / one-thread map queries, two runs (`--keep DIR [--reuse]`, load 1.9-2.2): ingest 13.8 /
11.6, slam 9.5 / 11.8 (mesh 5.4 / 6.5), register 12.9 / 12.2 (camera 2.7-3.0, extrinsic 2.3-2.6,
humans 6.5-6.7 | background 5.1-5.4, segment 1.9), raytrace-gt 13.5 / 12.0 s: slam+register 22.4 /
24.1 s = 1.66x / 2.01x raytrace-gt wall, 45 / 51 % of the pipeline; largest stage ingest / register
(by 0.2 s). Unchanged within noise: what bounds it is CPU (the camera half alone ~12 s wall; the
LiDAR half 7-8 s beside it; slam's Poisson 3.5 s), not waiting.

2026-12-02 ~06:25 UTC after register's anchored hold (results on this corner unchanged: no held
direction), `--keep DIR --reuse`, two runs at load ~1.5: ingest 11.1 / 10.0, slam 10.8 / 10.4,
register 12.3 / 11.0 (camera 1.8-3.3, extrinsic 2.3-2.5, humans 6.0-6.3 | background 4.9-5.3,
segment 1.8), raytrace-gt 12.4 / 11.4 s: slam+register 23.1 / 21.4 s = 1.86x / 1.88x raytrace-gt
wall, 50 % of the pipeline; largest stage raytrace-gt. Tried that day and dropped: the human
candidates of half the frames in a second process (register 12.8 / 12.8 s in two runs: the LiDAR
half's segmentation still runs then, three processes on two cores); the segmentation's background
model with voxel centroids from the free-space test's 80 scans only (model 3.3 -> 1.2 s, but twice
the foreground returns, so segmentation 1.6 -> 4.8 s); the model from a 120-scan subset (AP50
unchanged on a 160-cycle corner with two walkers, 0.80 instead of >= 0.9 on a 10-scan one at half).

2026-12-02 ~08:15 UTC, after the background model's centroids summed scan by scan (model 3.1 -> 1.25 s),
the human candidates of half the frames in a second process, static_depth_of from one sorted copy and
read-only ragged views (same register output), `--keep DIR --reuse`, two runs at load 1.7-2.2: ingest
25.4 (cold page cache) / 11.0, slam 9.7 / 10.8, register 10.8 / 10.0 (camera 1.7-2.3, extrinsic 1.9-2.0,
humans 5.8-6.1 | background 3.8, segment 2.2-2.3), raytrace-gt 10.6 / 10.3 s: slam+register 20.5 / 20.8 s =
1.94x / 2.02x raytrace-gt wall, 49 % of the pipeline in the warm run. register alone in a fresh process
(as ``holodata register`` runs) went from 10.3-12.4 to 9.5-10.0 s that day; inside this benchmark's one
process, after ingest and slam, it is slower (its forks copy a larger process). This machine (a VM)
pays ~7 us per page fault: sys time was ~25 % of slam+register's CPU. Tried that day and dropped: reading
the next ragged shard in a thread while the frames of this one are worked on (candidates 1.8-1.9 -> 2.2-
2.5 s: no core is free while the LiDAR half runs); glibc malloc settings that keep freed memory
(MALLOC_MMAP_THRESHOLD_/TRIM_THRESHOLD_: register's faults 370 k -> 160 k, no clear gain in wall time);
numpy without transparent huge pages (register 9.5-10.0 -> 10.0-10.3 s); slam segmenting the scans in
a second process beside its mesh so that register has no LiDAR half (slam+register in three alternated
pairs 17.3 / 21.2 / 21.3 s vs 17.7 / 18.5 / 22.0 s before, and 19.3 / 21.2 / 19.0 vs 19.0 / 17.9 / 18.6 s:
slam's mesh phase grew 1-2 s, register shrank 0.5-0.9 s). What bounds it: CPU, ~31 s of it for
slam+register against raytrace-gt's ~20 s; register's camera half reads and projects 1.2 GB of
camera points (~4 s CPU) that a float32 depth image per frame would hold in 0.4 GB.
Then with ``parallel.release_free_memory`` where slam and register start (register right after slam
in one process: 10.97-11.29 -> 9.69-10.35 s in three alternated pairs), two runs at load 1.3-2.0 on a
machine slower than that morning (raytrace-gt 12.0-13.0 s instead of 10.3-10.6): ingest 30.4 (cold) /
11.7, slam 12.4 / 10.5, register 12.5 / 11.5, raytrace-gt 13.0 / 12.0 s: slam+register 1.92x / 1.83x
raytrace-gt wall, 48 % of the pipeline in the warm run; largest stage ingest (cold) / raytrace-gt.
``--repeat 3`` at ~08:47 UTC (load 1.0-2.4, the machine slower still): ingest 24.8 s (cold), medians slam
12.1 (11.2-14.4), register 13.7 (13.4-14.4), raytrace-gt 14.4 (13.6-15.0) s: 1.79x (passes 2.12x,
1.64x, 1.79x).

2026-12-02 ~10:35-11:00 UTC on a fresh machine of the same kind (code as at f0b1f45): `--keep DIR`
(synth 206 s; load 2.0): ingest 15.8, slam 10.1, register 10.9, raytrace-gt 12.6 s = 1.67x, 43 %;
then `--reuse --repeat 3` (idle, load 0.8-1.7): ingest 31.5 s (the recording had left the page
cache), medians slam 9.3 (9.1-10.5), register 12.1 (12.0-12.3), raytrace-gt 12.8 (12.7-12.8) s:
1.68x (passes 1.78x, 1.66x, 1.68x), 33 %. Tried that day and dropped: the first human picks of the
last 40 % of the frames in a second process once the LiDAR half is done (its outlier removal in
scipy, the same picks as open3d's): the picks phase did not get shorter (2.6-3.1 s vs 2.7-3.0 s;
each process ran ~40 % slower per frame beside the other); slam's mesh from at most 60 instead of
120 scans (50 instead of 78 on this corner): mesh F@5cm 0.998 both, aligned extrinsic 1.03 -> 1.07
cm, slam 10.8 -> 9.4 s in one pair; not taken: one pair is within this machine's noise, and fewer
scans at rest give the mesh's background model fewer looks at people walking there (unmeasured).

    .venv/bin/python benchmarks/pipeline.py [--frames 400] [--corner L] [--lidar 64x1024] [--camera 376x672] [--walkers 0]
                                            [--gt-diff] [--keep DIR] [--reuse] [--repeat N]

``--repeat N``: N passes of slam (recomputed), register and raytrace-gt after the one ingest; the
table shows each stage's median (and range), and the ratio of every pass.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from holodata.conventions import Grid, RangeBins  # noqa: E402
from holodata.dataset import create_dataset, open_dataset  # noqa: E402
from holodata.ingest import ingest  # noqa: E402


def cpu() -> float:
    """CPU seconds of this process and its finished children (ray-tracing workers), all threads."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def load() -> str:
    return "load %.1f/%.1f/%.1f" % os.getloadavg()


def gt_range_diff(a_url: str, b_url: str) -> dict:
    """Per bounce: median and p90 |range_a - range_b| (cm) over beams with a return in both."""
    a, b = open_dataset(a_url), open_dataset(b_url)
    sa, sb = a.scene(a.scenes[0]), b.scene(b.scenes[0])
    ra = np.asarray(sa["gt/range"][...], np.float64)
    rb = np.asarray(sb["gt/range"][...], np.float64)
    out = {}
    for k in range(min(ra.shape[1], rb.shape[1])):  # gt/range (T, bounce, H, W)
        x, y = ra[:, k], rb[:, k]
        ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
        d = np.abs(x[ok] - y[ok]) * 100
        out[f"bounce{k + 1}"] = {"median_cm": float(np.median(d)) if len(d) else float("nan"),
                                 "p90_cm": float(np.percentile(d, 90)) if len(d) else float("nan"),
                                 "beams_both": int(ok.sum()),
                                 "only_one": int((np.isfinite(x) & (x > 0)).sum() + (np.isfinite(y) & (y > 0)).sum()
                                                 - 2 * ok.sum())}
    return out


STAGES = ("slam", "register", "raytrace-gt")


def mapping_and_gt(url: str, sid: str, work: Path) -> tuple[dict, dict, object, dict]:
    """One timed pass of slam (recomputed), register and raytrace-gt on the ingested dataset ``url``:
    (wall s by stage, CPU s by stage, slam's result, register's summary)."""
    from holodata.groundtruth import GTConfig, HumanDataset, raytrace_standalone
    from holodata.mapping import slam as S
    from holodata.mapping.register import register_scene
    from holodata.meshio import Mesh, write_ply
    from holodata.trajectory import Trajectory, write_tum

    rows, cpus = {}, {}
    t0, c0 = time.perf_counter(), cpu()
    res = S.slam_scene(url, sid, quiet=True, force=True)
    rows["slam"], cpus["slam"] = time.perf_counter() - t0, cpu() - c0
    ds = open_dataset(url)
    w = create_dataset(url, grid=ds.grid, range_bins=ds.range_bins).scene(sid)
    if "lidar/instance" in w.arrays():       # (a later pass's register segments again, as the first one does)
        w.remove("lidar/instance")
    t0, c0 = time.perf_counter(), cpu()
    reg = {}
    try:
        reg = register_scene(url, sid, quiet=True, force=True)
    except Exception as err:  # noqa: BLE001 - report and go on: the table still times it
        reg = {"error": str(err)[:200]}
    rows["register"], cpus["register"] = time.perf_counter() - t0, cpu() - c0
    sc = open_dataset(url).scene(sid)
    write_ply(work / "slam_mesh.ply", Mesh(res.mesh[0], res.mesh[1]))
    write_tum(work / "radar.tum", Trajectory(np.asarray(sc["time/timestamp_ns"][...], np.int64), res.T_world_radar))
    shutil.rmtree(work / "gt.zarr", ignore_errors=True)
    t0, c0 = time.perf_counter(), cpu()
    # what `holodata raytrace-gt DATASET` traces: the mesh and register's human surfaces, at 64x512
    # (the dataset's own radar grid is kept small to keep synth and ingest fast)
    raytrace_standalone(work / "slam_mesh.ply", work / "radar.tum", str(work / "gt.zarr"), cfg=GTConfig(),
                        human=HumanDataset(url, sid), quiet=True)
    rows["raytrace-gt"], cpus["raytrace-gt"] = time.perf_counter() - t0, cpu() - c0
    return rows, cpus, res, reg


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=400, help="radar cycles (2 Hz)")
    ap.add_argument("--corner", default="L")
    ap.add_argument("--lidar", default="64x1024", help="beams x columns (holodata synth's default)")
    ap.add_argument("--camera", default="376x672", help="rows x cols (holodata synth's default)")
    ap.add_argument("--radar-grid", default="16x64x32", help="synth radar heatmap H x W x range bins (ingest cost)")
    ap.add_argument("--walkers", type=int, default=0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--gt-diff", action="store_true", help="also compare SLAM-mesh GT with truth-mesh GT per bounce")
    ap.add_argument("--keep", default=None)
    ap.add_argument("--reuse", action="store_true", help="with --keep: reuse the synthesised recording there")
    ap.add_argument("--repeat", type=int, default=1, help="passes of slam, register and raytrace-gt (medians printed: "
                    "this 2-core machine's wall times vary by 10-20 %% from run to run)")
    args = ap.parse_args()
    from holodata.groundtruth import GTConfig, raytrace_standalone
    from holodata.mapping.accuracy import evaluate_slam
    from holodata.meshio import Mesh, write_ply
    from holodata.synth import synthesize

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="holodata-pipeline-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        rec = work / "syn" / "recording"
        truth_dir = work / "syn" / "truth"
        H, W, B = (int(v) for v in args.radar_grid.split("x"))
        if not (args.reuse and rec.exists()):
            shutil.rmtree(work / "syn", ignore_errors=True)
            t0 = time.perf_counter()
            synthesize(work / "syn", corner=args.corner, frames=args.frames, seed=args.seed, grid=Grid(H, W),
                       range_bins=RangeBins(B), lidar_shape=tuple(int(v) for v in args.lidar.split("x")),
                       camera_shape=tuple(int(v) for v in args.camera.split("x")), quiet=True,
                       visible_walkers=args.walkers)
            print(f"synth {time.perf_counter() - t0:.1f} s", flush=True)
        url = str(work / "ds.zarr")
        for p in (work / "ds.zarr", work / "gt.zarr", work / "gt_truth.zarr", work / "gt_slam_truthposes.zarr"):
            shutil.rmtree(p, ignore_errors=True)
        l0 = load()
        t0, c0 = time.perf_counter(), cpu()
        ingest([rec], url, quiet=True)
        ingest_s, ingest_cpu = time.perf_counter() - t0, cpu() - c0
        sid = open_dataset(url).scenes[0]
        passes = []
        for _ in range(max(1, args.repeat)):
            passes.append(mapping_and_gt(url, sid, work))
        rows = {"ingest": ingest_s, **{k: float(np.median([p[0][k] for p in passes])) for k in STAGES}}
        cpus = {"ingest": ingest_cpu, **{k: float(np.median([p[1][k] for p in passes])) for k in STAGES}}
        res, reg = passes[-1][2], passes[-1][3]
        l1 = load()
        acc = evaluate_slam(res.trajectory(), res.mesh, truth_dir)
        print(f"{args.corner} corner, {args.frames} radar cycles, LiDAR {args.lidar}, {res.summary['scans']} scans, "
              f"walkers {args.walkers} | slam ATE {acc['trajectory']['ate_rmse_m'] * 100:.2f} cm, mesh F@5cm "
              f"{acc['mesh']['f_5cm']:.3f} | {os.cpu_count()} cores, {l0} before, {l1} after")
        print(f"  slam phases {json.dumps(res.summary['timings'])}  health {json.dumps(res.summary['health'])}")
        print(f"  register phases {json.dumps(reg.get('timings', reg.get('error')))}")
        many = len(passes) > 1
        print(f"  {'stage':14s} {'wall s':>8s} {'CPU s':>8s}   (CPU: all threads and worker processes"
              + (f"; medians of {len(passes)} passes of slam, register, raytrace-gt, one ingest)" if many else ")"))
        for k, v in rows.items():
            spread = ""
            if many and k in STAGES:
                w = [p[0][k] for p in passes]
                spread = f"   ({min(w):.1f}-{max(w):.1f})"
            print(f"  {k:14s} {v:8.1f} {cpus[k]:8.1f}{spread}")
        sr, sc_ = rows["slam"] + rows["register"], cpus["slam"] + cpus["register"]
        print(f"  {'slam+register':14s} {sr:8.1f} {sc_:8.1f}   = {sr / rows['raytrace-gt']:.2f}x raytrace-gt wall, "
              f"{sc_ / cpus['raytrace-gt']:.2f}x its CPU (slam alone {rows['slam'] / rows['raytrace-gt']:.2f}x wall, "
              f"{cpus['slam'] / cpus['raytrace-gt']:.2f}x CPU)", flush=True)
        if many:
            ratios = [(p[0]["slam"] + p[0]["register"]) / p[0]["raytrace-gt"] for p in passes]
            print("  (slam+register) / raytrace-gt per pass: " + ", ".join(f"{r:.2f}x" for r in ratios))
        total = sum(rows.values())
        print(f"  slam+register = {100 * sr / total:.0f} % of the pipeline's wall time (ingest + slam + register + "
              f"raytrace-gt = {total:.1f} s); largest stage: {max(rows, key=rows.get)}", flush=True)
        if args.gt_diff:
            from holodata.meshio import read_mesh

            tm = read_mesh(truth_dir / "mesh.ply")
            hum = [k for k, n in tm.class_names.items() if str(n) == "human"]
            keep = ~np.isin(tm.face_class, hum) if tm.face_class is not None else np.ones(len(tm.faces), bool)
            write_ply(work / "truth_static.ply", Mesh(tm.vertices, tm.faces[keep]))
            raytrace_standalone(work / "truth_static.ply", truth_dir / "trajectory_radar.tum",
                                str(work / "gt_truth.zarr"), cfg=GTConfig(), quiet=True)
            # the SLAM GT again at the true radar poses: the difference is the mesh's alone
            raytrace_standalone(work / "slam_mesh.ply", truth_dir / "trajectory_radar.tum",
                                str(work / "gt_slam_truthposes.zarr"), cfg=GTConfig(), quiet=True)
            d = gt_range_diff(str(work / "gt_slam_truthposes.zarr"), str(work / "gt_truth.zarr"))
            print("  GT range |slam mesh - true mesh| (true radar poses): " + "  ".join(
                f"{k} median {v['median_cm']:.1f} cm p90 {v['p90_cm']:.1f} cm ({v['beams_both']} beams)"
                for k, v in d.items()))
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
