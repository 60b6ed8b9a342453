"""A small synthetic corner for the mapping tests (part B): recorded with people walking in the robot's
corridor (visible to the LiDAR), ingested, with the *true* LiDAR/radar poses written into the dataset
(so segmentation and registration are tested without SLAM error). Built once per test process."""
from __future__ import annotations

import atexit
import functools
import shutil
import tempfile
from pathlib import Path


@functools.cache
def small_corner() -> tuple[str, str]:
    """(dataset path, truth dir) of an L corner, 10 radar frames, 2 visible walkers, standing or walking
    human per the seed."""
    from holodata.conventions import Grid, RangeBins
    from holodata.evaluate.register_accuracy import write_truth_poses
    from holodata.ingest import ingest
    from holodata.synth import SynthSpec, synthesize

    root = Path(tempfile.mkdtemp(prefix="holodata-mapping-"))
    atexit.register(shutil.rmtree, root, True)
    res = synthesize(root / "rec", SynthSpec(corner="L", width=2.2, frames=10, seed=1, grid=Grid(8, 32),
                                             range_bins=RangeBins(n=64), lidar_shape=(32, 512), camera_shape=(188, 336),
                                             visible_walkers=2), quiet=True)
    url = str(root / "ds.zarr")
    ingest([res.recording], url, scene_ids=["recording"], quiet=True)
    write_truth_poses(url, "recording", res.truth_dir)
    return url, str(res.truth_dir)
