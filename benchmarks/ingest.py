"""Ingest throughput and memory against bare rosbags deserialisation (plain script, not a test).

Writes two recordings with rosbags' own writer — a radar (2 Hz RadarHeatmap) + Ouster-layout LiDAR
(10 Hz organised PointCloud2, point_step 48) + 16UC1 depth camera (15 Hz, + CameraInfo) + TF (30 Hz)
recording of N radar frames and one of 4N — then, in the same run:

- bare: rosbags reads every message of the topics ingest uses and deserialises it with the bag's
  typestore (what ``AnyReader`` does), from a memoryview of the payload as ingest does (rosbags
  slices the CDR encapsulation header off its input, which copies a ``bytes`` payload): messages/s
  and MB/s of serialised payload;
- ingest: ``holodata.ingest.ingest`` of the same recording into a fresh dataset (index pass, sync,
  decode of the matched messages, BLAKE3 of the file (sha256 in older versions), compressed shard
  writes), in a child process so its peak RSS is its own;
- ratio = ingest messages/s / bare messages/s (floor 0.5, aim 0.8), and the peak RSS of the small
  and the 4x recording (should be about equal: memory flat in recording size);
- the physical pipeline: the work ingest cannot avoid, each step done by the raw library
  in this run — the bare read above + sha256 of the source file (hashlib) + Blosc-lz4 (numcodecs,
  byte shuffle, the dataset's own codec settings) of the very arrays ingest wrote, shard by shard,
  + writing those bytes to files; ratio = physical pipeline seconds / ingest seconds (floor 0.8).
  The steps run one after the other; ingest may overlap them on 2 cores, so the ratio can pass 1.
  Also printed: the same ratio with BLAKE3 in place of sha256 in the pipeline, and both sides' CPU.
  ``--repeat N`` alternates bare read, ingest and pipeline N times and keeps the best of each (on a
  shared machine a burst of other work otherwise lands on one side only). Results and dates:
  benchmarks/results/ingest.md.

Both sides read a warm page cache (bare runs twice first, best run counted; ingest follows).
Module imports happen before the timing on both sides. The output also gives CPU seconds (all
threads) of both sides and the load average: on a shared machine the CPU ratio is the steadier
number.

    .venv/bin/python benchmarks/ingest.py [--frames 40] [--format mcap|rosbag1|sqlite3]
        [--compression none|lz4|bz2|zstd] [--keep DIR] [--validate] [--repeat N]

Measurements, their dates and the load they ran under: benchmarks/results/ingest.md (the findings of
the earlier rounds — zarr's sharding encoder, lz4 instead of zstd, writer threads, header-only reads —
are kept there too).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _run import header

OUSTER = np.dtype({"names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "ambient", "range"],
                   "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
                   "offsets": [0, 4, 8, 16, 20, 24, 26, 28, 32], "itemsize": 48})
PF = {"<f4": 7, "<u4": 6, "<u2": 4}
TOPICS = ["/radar/heatmap", "/ouster/points", "/camera/depth/image_rect_raw", "/camera/depth/camera_info", "/tf",
          "/tf_static"]


def write_recording(path: Path, fmt: str, frames: int, radar=(128, 32, 256), lidar=(32, 512), depth=(188, 336),
                    compression: str = "none") -> dict:
    from scipy.spatial.transform import Rotation

    from holodata.messages import typestore_for

    store = typestore_for(1 if fmt == "rosbag1" else 2)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:
        from rosbags.typesys import get_types_from_msg

        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", "tf2_msgs/msg/TFMessage"))
    T = store.types
    if fmt == "rosbag1":
        from rosbags.rosbag1 import Writer

        w = Writer(path)
        if compression != "none":
            w.set_compression({"lz4": Writer.CompressionFormat.LZ4, "bz2": Writer.CompressionFormat.BZ2}[compression])
    else:
        from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

        w = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3)
        if compression != "none":
            w.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    w.open()
    types = {"/radar/heatmap": "holodata_msgs/msg/RadarHeatmap", "/ouster/points": "sensor_msgs/msg/PointCloud2",
             "/camera/depth/image_rect_raw": "sensor_msgs/msg/Image",
             "/camera/depth/camera_info": "sensor_msgs/msg/CameraInfo", "/tf": "tf2_msgs/msg/TFMessage",
             "/tf_static": "tf2_msgs/msg/TFMessage"}
    conns = {t: w.add_connection(t, ty, typestore=store) for t, ty in types.items()}
    ser = store.serialize_ros1 if fmt == "rosbag1" else store.serialize_cdr

    def hdr(t, frame):
        st = T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9)
        return T["std_msgs/msg/Header"](seq=0, stamp=st, frame_id=frame) if fmt == "rosbag1" else \
            T["std_msgs/msg/Header"](stamp=st, frame_id=frame)

    def tfm(items):
        out = []
        for t, p, c, M in items:
            q = Rotation.from_matrix(M[:3, :3]).as_quat()
            out.append(T["geometry_msgs/msg/TransformStamped"](header=hdr(t, p), child_frame_id=c, transform=T[
                "geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=M[0, 3], y=M[1, 3], z=M[2, 3]),
                                               rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))))
        return T["tf2_msgs/msg/TFMessage"](transforms=out)

    t0 = 1_700_000_000 * 10**9
    rng = np.random.default_rng(0)
    ev = [(t0, "static", 0)]
    span = frames * 500_000_000
    ev += [(t0 + 100_000_000 + k * 500_000_000 + 530_000_000, "radar", k) for k in range(frames)]
    ev += [(t0 + 50_000_000 + k * 100_000_000 + 3_000_000, "lidar", k) for k in range(span // 100_000_000 + 2)]
    ev += [(t0 + 70_000_000 + k * 66_666_667 + 25_000_000, "camera", k) for k in range(span // 66_666_667 + 2)]
    ev += [(t0 + k * 33_333_333 + 1_000_000, "odom", k) for k in range(span // 33_333_333 + 8)]
    ev.sort()
    rows, cols = lidar
    base = np.zeros((rows, cols), OUSTER)
    az = -2 * np.pi * np.arange(cols) / cols
    el = np.deg2rad(np.linspace(16, -16, rows))[:, None]
    K = np.array([[200.0, 0, depth[1] / 2], [0, 200.0, depth[0] / 2], [0, 0, 1]])
    n = 0
    nbytes = 0
    for log, kind, k in ev:
        if kind == "static":
            topic, msg = "/tf_static", tfm([(log, "base_link", "radar", np.eye(4)), (log, "base_link", "os_sensor", np.eye(4)),
                                            (log, "map", "odom", np.eye(4)), (log, "base_link", "camera", np.eye(4))])
        elif kind == "odom":
            M = np.eye(4)
            M[0, 3] = 0.3 * (log - t0) / 1e9
            topic, msg = "/tf", tfm([(log - 1_000_000, "odom", "base_link", M)])
        elif kind == "radar":
            s = t0 + 100_000_000 + k * 500_000_000
            hm = rng.gamma(1.0, 1.0, radar).astype("<f2")
            topic = "/radar/heatmap"
            msg = T["holodata_msgs/msg/RadarHeatmap"](
                header=hdr(s + 250_000_000, "radar"), cycle_start_ns=s, cycle_end_ns=s + 500_000_000,
                n_range=radar[0], n_elevation=radar[1], n_azimuth=radar[2], range_resolution=0.0375,
                elevation_max=float(np.deg2rad(45)), elevation_min=float(np.deg2rad(-45)), rotation_radius=0.105,
                range_origin="rotation_centre",
                encoding="float16", data=np.frombuffer(hm.tobytes(), np.uint8))
        elif kind == "lidar":
            r = rng.uniform(1, 8, (rows, cols)).astype(np.float32)
            a = base.copy()
            a["x"], a["y"], a["z"] = r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)
            a["range"] = (r * 1000).astype(np.uint32)
            a["t"] = (np.arange(cols) * (100_000_000 // cols))[None, :]
            fields = [T["sensor_msgs/msg/PointField"](name=nm, offset=OUSTER.fields[nm][1],
                                                      datatype=PF[OUSTER.fields[nm][0].str], count=1)
                      for nm in OUSTER.names]
            topic = "/ouster/points"
            msg = T["sensor_msgs/msg/PointCloud2"](header=hdr(log - 3_000_000, "os_sensor"), height=rows, width=cols,
                                                   fields=fields, is_bigendian=False, point_step=48, row_step=48 * cols,
                                                   data=np.frombuffer(a.tobytes(), np.uint8), is_dense=False)
        else:
            d = rng.integers(300, 6000, depth).astype("<u2")
            stamp = log - 25_000_000
            img = T["sensor_msgs/msg/Image"](header=hdr(stamp, "camera"), height=depth[0], width=depth[1], encoding="16UC1",
                                             is_bigendian=0, step=2 * depth[1], data=np.frombuffer(d.tobytes(), np.uint8))
            roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
            kw = {"d": np.zeros(5), "k": K.ravel(), "r": np.eye(3).ravel(), "p": np.c_[K, np.zeros(3)].ravel()}
            if fmt == "rosbag1":
                kw = {x.upper(): v for x, v in kw.items()}
            info = T["sensor_msgs/msg/CameraInfo"](header=hdr(stamp, "camera"), height=depth[0], width=depth[1],
                                                   distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi, **kw)
            data = ser(info, types["/camera/depth/camera_info"])
            w.write(conns["/camera/depth/camera_info"], log, data)
            n += 1
            nbytes += len(data)
            topic, msg = "/camera/depth/image_rect_raw", img
        data = ser(msg, types[topic])
        w.write(conns[topic], log, data)
        n += 1
        nbytes += len(data)
    w.close()
    return {"messages": n, "bytes": nbytes}


def bare_rosbags(path: Path, fmt: str, repeat: int = 2) -> dict:
    """Read + deserialise every message of TOPICS with rosbags (AnyReader's typestore), best of
    ``repeat`` (the first run also warms the page cache); wall and CPU seconds of the best run."""
    from rosbags.highlevel import AnyReader

    best = None
    for _ in range(repeat):
        t, c0 = time.perf_counter(), time.process_time()
        n = nb = 0
        with AnyReader([path]) as r:
            conns = [c for c in r.connections if c.topic in TOPICS]
            for c, _, raw in r.messages(conns):
                r.deserialize(memoryview(raw), c.msgtype)    # a view: rosbags' CDR slice of bytes copies
                n += 1
                nb += len(raw)
        dt, dc = time.perf_counter() - t, time.process_time() - c0
        if best is None or dt < best[0]:
            best = (dt, dc)
    return {"seconds": best[0], "cpu_s": best[1], "messages": n, "bytes": nb}


def holodata_readers(path: Path) -> dict:
    """The same read + deserialise through holodata.readers (open_recording, raw_messages, decode)."""
    from holodata.readers import open_recording

    best = None
    for _ in range(2):
        t = time.perf_counter()
        n = 0
        with open_recording(path) as r:
            for raw in r.raw_messages(TOPICS):
                r.decode(raw)
                n += 1
        dt = time.perf_counter() - t
        best = dt if best is None else min(best, dt)
    return {"seconds": best, "messages": n}


def physical_pipeline(rec: Path, dataset: Path, bare_s: float, work: Path) -> dict:
    """Seconds of the unavoidable steps (module docstring): ``bare_s`` + sha256 of the source +
    Blosc-lz4 of every array of the ingested dataset at its shard size + writing the bytes."""
    import hashlib
    import warnings

    import zarr
    from numcodecs import Blosc

    warnings.filterwarnings("ignore", message="Object at .* is not recognized")   # holodata's manifest/ folder

    files = [rec] if rec.is_file() else sorted(p for p in rec.rglob("*") if p.suffix in (".mcap", ".db3", ".bag"))
    t = time.perf_counter()
    cpu = time.process_time()
    for f in files:
        h = hashlib.sha256()
        with open(f, "rb") as fh:
            while block := fh.read(8 << 20):
                h.update(block)
    sha_s = time.perf_counter() - t
    sha_cpu = time.process_time() - cpu
    import blake3  # what ingest hashes the source with (source.blake3): timed beside, not counted

    t = time.perf_counter()
    for f in files:
        h = blake3.blake3(max_threads=blake3.blake3.AUTO)
        with open(f, "rb") as fh:
            while block := fh.read(8 << 20):
                h.update(block)
    b3_s = time.perf_counter() - t
    blosc = Blosc(cname="lz4", clevel=5, shuffle=Blosc.SHUFFLE)
    root = zarr.open_group(str(dataset), mode="r")
    arrays, stack = [], [root]
    while stack:
        g = stack.pop()
        arrays += [a for _, a in g.arrays()]
        stack += [sg for _, sg in g.groups()]
    work.mkdir(parents=True, exist_ok=True)
    comp_s = write_s = cpu_s = 0.0
    nbytes = 0
    for i, a in enumerate(arrays):
        data = np.ascontiguousarray(a[...])                       # decoded: not timed
        step = (a.shards or a.chunks)[0] if data.ndim else 1
        for j in range(0, max(len(data), 1), max(step, 1)):
            block = data[j:j + step] if data.ndim else data
            t, c = time.perf_counter(), time.process_time()
            enc = blosc.encode(block)
            t1 = time.perf_counter()
            with open(work / f"{i}_{j}", "wb") as fh:
                fh.write(enc)
            write_s += time.perf_counter() - t1
            cpu_s += time.process_time() - c
            comp_s += t1 - t
            nbytes += block.nbytes
    shutil.rmtree(work, ignore_errors=True)
    return {"seconds": bare_s + sha_s + comp_s + write_s, "cpu_s": sha_cpu + cpu_s, "read_s": bare_s, "sha256_s": sha_s,
            "blake3_s": b3_s,
            "lz4_s": comp_s,
            "write_s": write_s, "array_mb": nbytes / 1e6, "arrays": len(arrays)}


CHILD = r"""
import json, sys, time
from holodata.ingest import ingest
import holodata.dataset.writer, holodata.readers.rosbag, holodata.readers.pointcloud2, zarr, rosbags.highlevel  # imports
import holodata.readers.mcap_file, holodata.readers.sqlite, holodata.readers.images, holodata.trajectory  # outside timing
import jsonschema, rosbags.typesys.stores.ros2_humble, rosbags.typesys.stores.ros1_noetic  # (docs/design/performance.md)
def hwm():  # this process image's own peak (VmHWM): ru_maxrss carries the forking parent's peak over exec
    return next(int(ln.split()[1]) for ln in open("/proc/self/status") if ln.startswith("VmHWM:")) / 1024
rss0 = hwm()
t, c = time.perf_counter(), time.process_time()
s = ingest([sys.argv[1]], sys.argv[2], quiet=True)
dt, dc = time.perf_counter() - t, time.process_time() - c
assert s["ok"], s
sc = s["scenes"][0]
print(json.dumps({"seconds": dt, "cpu_s": dc, "frames": sc["frames"], "decoded": sc["decoded"], "timings": sc["timings"],
                  "rss_mb": hwm(), "rss_imports_mb": rss0}))
"""


def run_ingest(path: Path, out: Path) -> dict:
    res = subprocess.run([sys.executable, "-c", CHILD, str(path), str(out)], capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"ingest failed: {res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=40, help="radar frames of the small recording (the large has 4x)")
    ap.add_argument("--format", default="mcap", choices=["mcap", "rosbag1", "sqlite3"])
    ap.add_argument("--compression", default="none", choices=["none", "lz4", "bz2", "zstd"],
                    help="chunk compression (rosbag1: lz4|bz2) or per-message zstd (rosbag2 mcap/sqlite3)")
    ap.add_argument("--keep", help="write the recordings and datasets here and keep them")
    ap.add_argument("--validate", action="store_true", help="also run validate on each ingested dataset (untimed)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="run bare read, ingest and the physical pipeline this many times, alternated; best of each")
    args = ap.parse_args()
    header()
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="holodata-bench-ingest-"))
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs", flush=True)
    try:
        for mult in (1, 4):
            name = f"rec{mult}x" + (".bag" if args.format == "rosbag1" else "")
            rec = root / name
            if rec.exists():
                shutil.rmtree(rec) if rec.is_dir() else rec.unlink()
            t = time.perf_counter()
            if (args.format == "rosbag1") != (args.compression in ("none", "lz4", "bz2")) and args.compression != "none":
                raise SystemExit("--compression lz4|bz2 go with --format rosbag1, zstd with mcap|sqlite3")
            write_recording(rec, args.format, args.frames * mult, compression=args.compression)
            tw = time.perf_counter() - t
            hr = holodata_readers(rec)
            out = root / f"ds{mult}x.zarr"
            load = os.getloadavg()
            loads = []
            bare = ing = phys = None
            for _ in range(args.repeat):    # alternated, best of each side: other jobs' bursts hit both alike
                loads.append(round(os.getloadavg()[0], 2))     # 1-min load average at the start of each round
                b = bare_rosbags(rec, args.format)    # run 1 warms the page cache: both sides read a warm file
                bare = b if bare is None or b["seconds"] < bare["seconds"] else bare
                shutil.rmtree(out, ignore_errors=True)
                i = run_ingest(rec, out)
                ing = i if ing is None or i["seconds"] < ing["seconds"] else ing
                ph = physical_pipeline(rec, out, 0.0, root / "physical")
                phys = ph if phys is None or ph["seconds"] < phys["seconds"] else phys
            phys = {**phys, "seconds": phys["seconds"] + bare["seconds"], "read_s": bare["seconds"],
                    "cpu_s": phys["cpu_s"] + bare["cpu_s"]}
            if args.validate:
                from holodata.dataset.validate import validate_dataset

                rep = validate_dataset(str(out))
                assert rep["ok"], rep["problems"][:3]
            size = sum(p.stat().st_size for p in ([rec] if rec.is_file() else rec.rglob("*")) if p.is_file())
            mb = bare["bytes"] / 1e6
            row = {"recording": name, "frames": ing["frames"], "messages": bare["messages"], "payload_mb": round(mb, 1),
                   "file_mb": round(size / 1e6, 1), "write_s": round(tw, 2),
                   "bare_s": round(bare["seconds"], 3), "bare_msg_s": round(bare["messages"] / bare["seconds"], 1),
                   "bare_mb_s": round(mb / bare["seconds"], 1),
                   "ingest_s": round(ing["seconds"], 3), "ingest_msg_s": round(bare["messages"] / ing["seconds"], 1),
                   "ingest_mb_s": round(mb / ing["seconds"], 1), "ratio": round(bare["seconds"] / ing["seconds"], 3),
                   "readers_s": round(hr["seconds"], 3), "readers_ratio": round(bare["seconds"] / hr["seconds"], 3),
                   "peak_rss_mb": round(ing["rss_mb"], 1), "rss_after_imports_mb": round(ing["rss_imports_mb"], 1),
                   "bare_cpu_s": round(bare["cpu_s"], 3), "ingest_cpu_s": round(ing["cpu_s"], 3),
                   "cpu_ratio": round(bare["cpu_s"] / ing["cpu_s"], 3), "loadavg": [round(x, 2) for x in load],
                   "loadavg_per_round": loads,
                   "page_cache": "warm", "decoded": ing["decoded"], "timings": ing["timings"],
                   "physical": {k: round(v, 3) for k, v in phys.items()},
                   "physical_ratio": round(phys["seconds"] / ing["seconds"], 3),
                   "physical_ratio_blake3": round((phys["seconds"] - phys["sha256_s"] + phys["blake3_s"]) / ing["seconds"], 3),
                   "physical_cpu_ratio": round(phys["cpu_s"] / ing["cpu_s"], 3)}
            rows.append(row)
            print(f"{name:10s} {row['frames']:4d} frames {row['messages']:6d} msgs {row['payload_mb']:7.1f} MB | bare rosbags "
                  f"{row['bare_msg_s']:8.1f} msg/s {row['bare_mb_s']:7.1f} MB/s | ingest {row['ingest_msg_s']:8.1f} msg/s "
                  f"{row['ingest_mb_s']:7.1f} MB/s | ratio {row['ratio']:.2f} (floor 0.5, aim 0.8) | peak RSS "
                  f"{row['peak_rss_mb']:.0f} MB", flush=True)
            print(f"{'':10s} physical pipeline {phys['seconds']:.2f} s (read {phys['read_s']:.2f} + sha256 "
                  f"{phys['sha256_s']:.2f} + Blosc-lz4 {phys['lz4_s']:.2f} + write {phys['write_s']:.2f} s of "
                  f"{phys['array_mb']:.0f} MB in {phys['arrays']} arrays) / ingest {ing['seconds']:.2f} s = ratio "
                  f"{row['physical_ratio']:.2f} (floor 0.8); with BLAKE3 (ingest's source digest, "
                  f"{phys['blake3_s']:.2f} s) in place of sha256: ratio {row['physical_ratio_blake3']:.2f}", flush=True)
            tm = ing["timings"]
            print(f"{'':10s} ingest {ing['seconds']:.2f} s = index pass {tm['index_pass_s']:.2f} s + write pass "
                  f"{tm['write_pass_s']:.2f} s (decode {tm['decode_s']:.2f} s; shard writes {tm['store_s']:.2f} s busy "
                  f"summed over the writer threads) + sha256/attrs; bare rosbags {bare['seconds']:.2f} s; "
                  f"holodata.readers read+deserialise {hr['seconds']:.2f} s (ratio {row['readers_ratio']:.2f})", flush=True)
            print(f"{'':10s} CPU s (all threads): ingest {ing['cpu_s']:.2f}, physical pipeline {phys['cpu_s']:.2f} (ratio "
                  f"{row['physical_cpu_ratio']:.2f}), bare {bare['cpu_s']:.2f} (ratio {row['cpu_ratio']:.2f}); "
                  f"page cache warm for both; load average before ingest "
                  f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs (1-min at each round: "
                  f"{' '.join(f'{x:.1f}' for x in loads)})", flush=True)
        r1, r4 = rows
        print(f"peak RSS 4x / 1x: {r4['peak_rss_mb'] / r1['peak_rss_mb']:.2f} (flat memory: about 1)")
        print(json.dumps({"format": args.format, "compression": args.compression, "rows": rows}))
    finally:
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
