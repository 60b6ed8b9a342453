"""``ingest --list``: what a recording holds and the roles ingest would use."""
from __future__ import annotations

from pathlib import Path

from ..errors import HolodataError, one_line
from ..readers import open_recording
from .plan import _reject_reason
from .roles import ROLES, TopicMap, load_topics_file, map_topics


def list_recording(path, msg_dir=None, meta=None, topics=None, beamform=None, motion=None) -> dict:
    """What ``ingest --list`` prints: reader, files, duration, topics (name, type, count, rate,
    frame id), the role ingest would give each (with ``topics``: dict or YAML path overrides) and
    the reader's ``decisions`` (e.g. which rule made a PanoRadar trajectory static; ``motion``
    overrides it, as in :func:`holodata.ingest.ingest`)."""
    if isinstance(topics, (str, Path)):
        topics = load_topics_file(topics)
    rec = open_recording(path, msg_dir=msg_dir, meta=meta, beamform=beamform, motion=motion)
    try:
        infos = rec.topics(frame_ids=True)
        try:
            tmap, notes = map_topics(rec, topics, infos)
        except HolodataError as err:
            tmap, notes = TopicMap(), [one_line(err)]
        roles = {}
        for r in ROLES:
            v = getattr(tmap, r)
            for name in ([v] if isinstance(v, str) else v or []):
                roles[name] = r
        lo, hi = rec.duration_ns()
        size = sum(f.stat().st_size for f in rec.files if f.exists())
        usable = bool(tmap.radar or tmap.lidar)
        reason = None if usable else _reject_reason(rec, infos, tmap, notes)
        lidar_type = next((t.msgtype for t in infos if t.name == tmap.lidar), None) if tmap.lidar else None
        if usable and lidar_type is not None:
            from ..readers.ouster import SDK_TYPES, sdk_missing

            reason = sdk_missing() if lidar_type in SDK_TYPES else None   # ingest would stop there
            usable = reason is None
        return {"recording": str(rec.path), "reader": rec.kind, "files": [str(f) for f in rec.files], "bytes": size,
                "start_ns": lo, "end_ns": hi, "duration_s": None if lo is None else (hi - lo) / 1e9,
                "messages": sum(t.count for t in infos), "truncated": bool(rec.truncated),
                "problems": list(rec.problems), "decisions": dict(rec.decisions), "notes": notes,
                "ingestable": usable, "reason": reason,
                "topics": [{**t.to_dict(), "role": roles.get(t.name)} for t in infos]}
    finally:
        rec.close()


def format_listing(info: dict) -> str:
    """``ros2 bag info``-like text of :func:`list_recording`'s result."""
    mb = info["bytes"] / 1e6
    lines = [f"Files:     {', '.join(Path(f).name for f in info['files'])} ({mb:.1f} MB)",
             f"Reader:    {info['reader']}" + ("  (TRUNCATED: readable part only)" if info["truncated"] else "")]
    if info["duration_s"] is not None:
        lines.append(f"Duration:  {info['duration_s']:.3f} s   Start: {info['start_ns']} ns   End: {info['end_ns']} ns")
    lines.append(f"Messages:  {info['messages']}")
    lines.append(f"Topics:    {len(info['topics'])}")
    w = max([len(t["name"]) for t in info["topics"]] + [5])
    wt = max([len(t["type"]) for t in info["topics"]] + [4])
    for t in info["topics"]:
        rate = f"{t['rate_hz']:.2f} Hz" if t["rate_hz"] else "-"
        extra = []
        if t.get("frame_id"):
            extra.append(f"frame {t['frame_id']}")
        if t.get("role"):
            extra.append(f"[{t['role']}]")
        if not t["decodable"]:
            extra.append(f"({t.get('note') or 'not decodable'})")
        lines.append(f"  {t['name']:<{w}}  {t['type']:<{wt}}  {t['count']:>7}  {rate:>11}  {' '.join(extra)}".rstrip())
    for what, how in info.get("decisions", {}).items():
        lines.append(f"{what.capitalize() + ':':<10} {how}")
    for p in info["problems"]:
        lines.append(f"warning: {p}")
    for n in info["notes"]:
        lines.append(f"note: {n}")
    lines.append("Ingest:    " + ("yes" if info["ingestable"] else f"no — {info['reason']}"))
    return "\n".join(lines)
