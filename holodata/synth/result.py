"""What :func:`~holodata.synth.synthesis.synthesize` returns: :class:`SynthResult`."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class SynthResult:
    """Paths and counts of one synthetic recording.

    ``recording``: the rosbag2 directory or the ROS 1 ``.bag``; ``storage_file``: the file holding the
    messages (``.mcap``/``.db3``/``.bag``); ``truth_dir`` and its main files; ``topics`` {topic: type};
    ``counts`` {topic: messages}; ``stats``: LiDAR returns on the human (must be 0), median LOS→NLOS
    drop (dB), etc.
    """

    out_dir: Path
    recording: Path
    storage_file: Path
    format: str
    truth_dir: Path
    scene_json: Path
    mesh: Path
    trajectory_radar: Path
    trajectory_base: Path
    human_dir: Path | None
    n_frames: int
    corner: str
    width_m: float
    seed: int
    human: bool
    topics: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    mapping_recording: Path | None = None   # the mapping pass (``mapping_pass=True``), else None
    trajectory_lidar_mapping: Path | None = None

    def summary(self) -> dict:
        return {k: (str(v) if isinstance(v, Path) else v) for k, v in self.__dict__.items()}
