"""Procedural indoor corners (T, L, cross, oblique: branch at 45° to the approach corridor) as closed triangle meshes with
materials.

World frame (REP-103): the robot's *approach corridor* runs along +x with its axis on y = 0
and its walls at y = ±width/2; the junction starts at x = 0. The *hidden branch* (where the
human walks) leaves the junction towards +y (mirrored worlds: -y); the convex corner at
(0, ±width/2) occludes it from the approach corridor. Walls are vertical, floor at z = 0,
ceiling at z = height, so plan-view (2-D) occlusion is exact for the walls.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

CORNER_TYPES = ("T", "L", "cross", "oblique")


@dataclass(frozen=True)
class Material:
    """Surface material.

    ``rf_reflectivity``: backscatter power coefficient at normal incidence (0..1);
    ``rf_loss_db``: power lost per specular bounce (dB, > 0), paid twice on a round trip;
    ``rf_diffuse``: fraction of backscatter that is diffuse (∝ cos incidence) rather than in the
    specular lobe; ``lidar_reflectivity``: near-IR Lambertian reflectivity (0..1).
    """

    name: str
    rf_reflectivity: float
    rf_loss_db: float
    rf_diffuse: float
    lidar_reflectivity: float


MATERIALS: tuple[Material, ...] = (
    Material("drywall", 0.50, 6.0, 0.10, 0.60),
    Material("concrete", 0.70, 3.0, 0.15, 0.40),
    Material("brick", 0.60, 4.5, 0.20, 0.35),
    Material("glass", 0.45, 8.0, 0.02, 0.06),
    Material("wood", 0.40, 7.0, 0.10, 0.50),
    Material("metal", 0.95, 0.5, 0.05, 0.70),
    Material("vinyl_floor", 0.30, 9.0, 0.10, 0.30),
    Material("carpet", 0.15, 12.0, 0.20, 0.15),
    Material("ceiling_tile", 0.20, 10.0, 0.30, 0.80),
    Material("cardboard", 0.15, 12.0, 0.30, 0.50),
    Material("human", 0.80, 6.0, 0.60, 0.30),
)
MATERIAL_ID = {m.name: i for i, m in enumerate(MATERIALS)}
WALL_MATERIALS = ("drywall", "concrete", "brick")
FLOOR_MATERIALS = ("vinyl_floor", "carpet", "concrete")
CEILING_MATERIALS = ("ceiling_tile", "concrete", "drywall")

# per-face semantic classes (uint8); 0 is reserved for "unknown"
CLASS_NAMES = {1: "floor", 2: "ceiling", 3: "wall", 4: "door", 5: "pillar", 6: "box", 7: "human"}
CLASS_ID = {v: k for k, v in CLASS_NAMES.items()}


@dataclass
class World:
    """A static corner scene.

    ``vertices`` (V,3) float64 m, ``faces`` (F,3) int32 (normals face the free space),
    ``face_material`` (F,) uint8 index into ``materials``, ``face_class`` (F,) uint8 (``class_names``).
    ``floor_polygon`` (P,2) the free-space outline (counter-clockwise). ``robot_start``/``robot_stop``
    (2,) plan positions on the approach corridor axis region; ``hidden_axis``: (origin (2,),
    unit direction (2,), length m, width m) of the hidden branch's centre line.
    """

    corner: str
    width: float
    hidden_width: float
    height: float
    seed: int
    mirrored: bool
    vertices: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    face_class: np.ndarray
    floor_polygon: np.ndarray
    robot_start: np.ndarray
    robot_stop: np.ndarray
    hidden_axis: tuple
    features: list = field(default_factory=list)
    materials: tuple = MATERIALS
    class_names: dict = field(default_factory=lambda: dict(CLASS_NAMES))

    def describe(self) -> dict:
        """JSON-able description (no arrays but the outline)."""
        used = sorted(set(int(m) for m in np.unique(self.face_material)))
        return {
            "corner_type": self.corner,
            "width_m": round(self.width, 4),
            "hidden_width_m": round(self.hidden_width, 4),
            "height_m": round(self.height, 4),
            "mirrored": self.mirrored,
            "seed": self.seed,
            "n_vertices": int(len(self.vertices)),
            "n_faces": int(len(self.faces)),
            "floor_polygon": np.round(self.floor_polygon, 4).tolist(),
            "features": self.features,
            "materials": {str(i): vars(self.materials[i]) for i in used},
            "surface_materials": self._surface_materials(),
            "class_names": {str(k): v for k, v in self.class_names.items()},
        }

    def _surface_materials(self) -> dict:
        out = {}
        for cid, name in self.class_names.items():
            sel = self.face_class == cid
            if sel.any():
                out[name] = sorted({self.materials[int(m)].name for m in np.unique(self.face_material[sel])})
        return out


# ------------------------------------------------------------------ mesh helpers
class _MeshBuilder:
    def __init__(self) -> None:
        self.v: list[np.ndarray] = []
        self.f: list[np.ndarray] = []
        self.mat: list[np.ndarray] = []
        self.cls: list[np.ndarray] = []
        self.n = 0

    def add(self, verts, faces, material: str, cls: str) -> None:
        verts = np.asarray(verts, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64) + self.n
        self.v.append(verts)
        self.f.append(faces)
        self.mat.append(np.full(len(faces), MATERIAL_ID[material], np.uint8))
        self.cls.append(np.full(len(faces), CLASS_ID[cls], np.uint8))
        self.n += len(verts)

    def arrays(self):
        return (np.concatenate(self.v), np.concatenate(self.f).astype(np.int32),
                np.concatenate(self.mat), np.concatenate(self.cls))


def box_mesh(center, size, yaw: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Closed box: 8 vertices, 12 outward-facing triangles. ``size`` (sx, sy, sz) m."""
    sx, sy, sz = (np.asarray(size, dtype=np.float64) / 2.0)
    corners = np.array([[x, y, z] for z in (-sz, sz) for y in (-sy, sy) for x in (-sx, sx)])
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    v = corners @ R.T + np.asarray(center, dtype=np.float64)
    f = np.array([
        [0, 2, 1], [1, 2, 3],  # bottom (-z)
        [4, 5, 6], [5, 7, 6],  # top (+z)
        [0, 1, 4], [1, 5, 4],  # -y
        [2, 6, 3], [3, 6, 7],  # +y
        [0, 4, 2], [2, 4, 6],  # -x
        [1, 3, 5], [3, 7, 5],  # +x
    ])
    return v, f


def triangulate_polygon(poly: np.ndarray) -> np.ndarray:
    """Ear-clipping triangulation of a simple counter-clockwise polygon (P,2) -> (P-2,3) int."""
    idx = list(range(len(poly)))
    tris = []
    guard = 0
    while len(idx) > 3 and guard < 10000:
        guard += 1
        n = len(idx)
        for k in range(n):
            a, b, c = idx[(k - 1) % n], idx[k], idx[(k + 1) % n]
            pa, pb, pc = poly[a], poly[b], poly[c]
            cross = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0])
            if cross <= 1e-12:
                continue  # reflex or degenerate
            ok = True
            for m in idx:
                if m in (a, b, c):
                    continue
                if _in_triangle(poly[m], pa, pb, pc):
                    ok = False
                    break
            if ok:
                tris.append((a, b, c))
                idx.pop(k)
                break
        else:
            raise ValueError("polygon triangulation failed (not simple or not counter-clockwise)")
    tris.append(tuple(idx))
    return np.asarray(tris, dtype=np.int64)


def _in_triangle(p, a, b, c) -> bool:
    def s(p1, p2, p3):
        return (p1[0] - p3[0]) * (p2[1] - p3[1]) - (p2[0] - p3[0]) * (p1[1] - p3[1])

    d1, d2, d3 = s(p, a, b), s(p, b, c), s(p, c, a)
    neg = (d1 < -1e-12) or (d2 < -1e-12) or (d3 < -1e-12)
    pos = (d1 > 1e-12) or (d2 > 1e-12) or (d3 > 1e-12)
    return not (neg and pos)


def polygon_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


# ------------------------------------------------------------------ floor plans
def _outline(corner: str, w: float, w2: float, la: float, lh: float, lc: float):
    """Counter-clockwise free-space outline, the hidden branch centre line and the edge tags.

    Returns (poly (P,2), hidden_axis (origin, dir, length, width)).
    """
    hw = w / 2.0
    if corner == "L":
        poly = [(-la, -hw), (w2, -hw), (w2, hw + lh), (0, hw + lh), (0, hw), (-la, hw)]
        axis = (np.array([w2 / 2, hw]), np.array([0.0, 1.0]), lh, w2)
    elif corner == "T":
        poly = [(-la, -hw), (0, -hw), (0, -hw - lh), (w2, -hw - lh), (w2, hw + lh), (0, hw + lh), (0, hw), (-la, hw)]
        axis = (np.array([w2 / 2, hw]), np.array([0.0, 1.0]), lh, w2)
    elif corner == "cross":
        poly = [(-la, -hw), (0, -hw), (0, -hw - lh), (w2, -hw - lh), (w2, -hw), (w2 + lc, -hw), (w2 + lc, hw),
                (w2, hw), (w2, hw + lh), (0, hw + lh), (0, hw), (-la, hw)]
        axis = (np.array([w2 / 2, hw]), np.array([0.0, 1.0]), lh, w2)
    elif corner == "oblique":
        # the hidden branch leaves the junction at 45° to the approach corridor (a 135° turn back
        # to the left): the corridors' axes meet at an acute 45° angle, the junction is a wedge
        u = np.array([-np.cos(np.pi / 4), np.sin(np.pi / 4)])
        nrm = np.array([u[1], -u[0]])  # right-hand normal of the branch direction
        P = np.array([0.0, hw])
        # the branch's outer wall P + w2*nrm + s*u meets the approach corridor's outer wall y = -hw
        s = (-hw - (P[1] + w2 * nrm[1])) / u[1]
        X = P + w2 * nrm + s * u
        poly = [(-la, -hw), tuple(X), tuple(P + w2 * nrm + lh * u), tuple(P + lh * u), tuple(P), (-la, hw)]
        axis = (P + 0.5 * w2 * nrm, u, lh, w2)
    else:
        raise ValueError(f"unknown corner type {corner!r} (choose from {', '.join(CORNER_TYPES)})")
    return np.asarray(poly, dtype=np.float64), axis


def _insert_notch(poly: np.ndarray, edge: int, t0: float, wid: float, depth: float):
    """Cut a rectangular recess (door) into edge ``edge`` of a CCW polygon, starting ``t0`` m along
    it. Returns the new polygon and the index of the recess's back edge."""
    a, b = poly[edge], poly[(edge + 1) % len(poly)]
    d = (b - a) / np.linalg.norm(b - a)
    out = np.array([d[1], -d[0]])  # outward normal (interior on the left of a CCW edge)
    p1 = a + d * t0
    p2 = p1 + out * depth
    p3 = p2 + d * wid
    p4 = p1 + d * wid
    new = np.concatenate([poly[:edge + 1], [p1, p2, p3, p4], poly[edge + 1:]])
    return new, edge + 2  # back edge runs p2 -> p3


def make_world(corner: str = "L", width: float | None = None, seed: int = 0, features: bool = True) -> World:
    """Build a seeded corner world.

    ``width``: approach-corridor width in metres (1.3–4.7; None = drawn from the seed). The hidden
    branch width is drawn within ±15 % of it. Height 2.5–3.2 m. Optional door recesses, pillars
    (pilasters against walls) and boxes on the floor, each drawn from the seed. The draws come in a
    fixed order (dimensions, surface materials, the building's RF properties, features, the robot's
    start and stop), so a given width leaves every other draw as it is.
    """
    if corner not in CORNER_TYPES:
        raise ValueError(f"unknown corner type {corner!r} (choose from {', '.join(CORNER_TYPES)})")
    rng = np.random.default_rng(seed)
    dims = _Dims.draw(corner, width, rng)
    wall_mat = WALL_MATERIALS[rng.integers(len(WALL_MATERIALS))]
    floor_mat = FLOOR_MATERIALS[rng.integers(len(FLOOR_MATERIALS))]
    ceil_mat = CEILING_MATERIALS[rng.integers(len(CEILING_MATERIALS))]
    materials = _building_materials(rng)
    poly, axis = _outline(corner, dims.width, dims.w2, dims.la, dims.lh, dims.lc)
    plan = _Floorplan(poly, wall_mat)
    if features:
        _wall_section(plan, rng)
        _door_recesses(plan, dims, rng)
        _pilasters(plan, dims, rng)
        _floor_boxes(plan, dims, rng)
    _shell(plan, dims.height, floor_mat, ceil_mat)
    V, F, M, C = plan.mb.arrays()
    robot_start = np.array([-float(rng.uniform(4.0, 5.5)), float(rng.uniform(-0.12, 0.12)) * dims.width])
    robot_stop = np.array([-float(rng.uniform(0.6, 1.2)), float(rng.uniform(-0.08, 0.08)) * dims.width])
    origin, direction, length, bw = axis
    poly = plan.poly
    if dims.mirrored:
        V = V * np.array([1.0, -1.0, 1.0])
        F = F[:, [0, 2, 1]]
        poly = (poly * np.array([1.0, -1.0]))[::-1].copy()
        robot_start = robot_start * np.array([1.0, -1.0])
        robot_stop = robot_stop * np.array([1.0, -1.0])
        origin = origin * np.array([1.0, -1.0])
        direction = direction * np.array([1.0, -1.0])
        for ft in plan.feats:
            if "center" in ft:
                ft["center"][1] = -ft["center"][1]
    return World(corner, dims.width, dims.w2, dims.height, int(seed), dims.mirrored, V, F.astype(np.int32), M, C, poly,
                 robot_start, robot_stop, (origin, direction, float(length), float(bw)), plan.feats, materials)


@dataclass(frozen=True)
class _Dims:
    """A corner's dimensions (m): approach-corridor ``width``, hidden-branch width ``w2``, ceiling
    ``height``, approach-corridor length ``la`` behind the junction, hidden-branch length ``lh``,
    the cross's continuation ``lc``; ``mirrored``: the hidden branch towards -y."""

    width: float
    w2: float
    height: float
    la: float
    lh: float
    lc: float
    mirrored: bool

    @classmethod
    def draw(cls, corner: str, width: float | None, rng: np.random.Generator) -> _Dims:
        if width is None:
            width = float(np.clip(rng.gamma(6.0, 0.36), 1.3, 4.7))
        else:
            width = float(width)
            rng.gamma(6.0, 0.36)  # keep the stream aligned whether or not width is given
        if not 0.8 <= width <= 8.0:
            raise ValueError(f"corridor width must be within 0.8–8 m, got {width}")
        w2 = float(np.clip(width * rng.uniform(0.85, 1.15), 1.2, 5.0))
        height = float(rng.uniform(2.5, 3.2))
        la = float(rng.uniform(7.0, 9.0))     # approach corridor length behind the junction
        lh = float(rng.uniform(6.5, 8.0))     # hidden branch length
        lc = float(rng.uniform(3.0, 5.0))     # cross: continuation length
        mirrored = bool(rng.random() < 0.5) if corner in ("L", "oblique", "T", "cross") else False
        return cls(width, w2, height, la, lh, lc, mirrored)


def _building_materials(rng: np.random.Generator) -> tuple[Material, ...]:
    """:data:`MATERIALS` as one building has them: per-building variation of the RF properties (paint,
    moisture, construction), so the LOS→NLOS power drop spans the paper's attenuation bands (< 10,
    10–20, > 20 dB): every loss scaled by one factor in 0.15–1.6 and ±15 % more, every reflectivity ±20 %."""
    loss_scale = float(rng.uniform(0.15, 1.6))
    return tuple(replace(m, rf_loss_db=round(m.rf_loss_db * loss_scale * float(rng.uniform(0.85, 1.15)), 3),
                         rf_reflectivity=round(min(1.0, m.rf_reflectivity * float(rng.uniform(0.8, 1.2))), 3))
                 for m in MATERIALS)


class _Floorplan:
    """The corner being built: its free-space outline ``poly`` (P,2) with each edge's wall material and
    class (door recesses insert edges), the meshes added so far and the features' descriptions."""

    def __init__(self, poly: np.ndarray, wall_mat: str):
        self.poly = poly
        self.wall_mat = wall_mat
        self.edge_mat = [wall_mat] * len(poly)
        self.edge_cls = ["wall"] * len(poly)
        self.feats: list[dict] = []
        self.mb = _MeshBuilder()


def _wall_section(plan: _Floorplan, rng: np.random.Generator) -> None:
    """A quarter of the time, a glass or different wall section on the long outer wall (edge 0)."""
    if rng.random() < 0.25:
        plan.edge_mat[0] = "glass" if rng.random() < 0.5 else WALL_MATERIALS[rng.integers(len(WALL_MATERIALS))]
        plan.feats.append({"kind": "wall_material", "edge": 0, "material": plan.edge_mat[0]})


def _door_recesses(plan: _Floorplan, dims: _Dims, rng: np.random.Generator) -> None:
    """Door recesses on the approach corridor's side walls (each half the time), behind the robot
    (x < -2.5 m): a wooden door 2.0-2.2 m high at the back of a 0.08-0.25 m deep notch, wall above it."""
    wall_mat, la, height = plan.wall_mat, dims.la, dims.height
    n_edges = len(plan.poly)
    for edge in (n_edges - 2, 0):  # the approach corridor's side walls (y = +w/2, y = -w/2)
        if rng.random() < 0.5:
            wid, depth = float(rng.uniform(0.85, 1.1)), float(rng.uniform(0.08, 0.25))
            # keep the recess in the far part of the approach corridor (x < -2.5)
            if edge == 0:
                t0 = float(rng.uniform(0.3, la - 2.5 - wid))
            else:
                t0 = float(rng.uniform(2.5, la - wid - 0.3))
            plan.poly, _ = _insert_notch(plan.poly, edge, t0, wid, depth)
            plan.edge_mat = plan.edge_mat[:edge + 1] + [wall_mat, "wood", wall_mat, wall_mat] + plan.edge_mat[edge + 1:]
            plan.edge_cls = plan.edge_cls[:edge + 1] + ["wall", "door", "wall", "wall"] + plan.edge_cls[edge + 1:]
            # the notch's edges: (edge) a->p1 (kept), p1->p2 side, p2->p3 back(door), p3->p4 side, p4->b
            p1, p2, p3, p4 = plan.poly[edge + 1: edge + 5]
            door_h = float(rng.uniform(2.0, 2.2))
            cen = (p1 + p3) / 2.0
            d = (p4 - p1) / np.linalg.norm(p4 - p1)
            v, f = box_mesh([cen[0], cen[1], (door_h + height) / 2 + 0.01],
                            [wid + 0.02, depth + 0.02, height - door_h + 0.02], np.arctan2(d[1], d[0]))
            plan.mb.add(v, f, wall_mat, "wall")
            plan.feats.append({"kind": "door_recess", "center": np.round(cen, 3).tolist(), "width": round(wid, 3),
                               "depth": round(depth, 3), "door_height": round(door_h, 3)})


def _pilasters(plan: _Floorplan, dims: _Dims, rng: np.random.Generator) -> None:
    """0-2 pilasters: half-embedded pillars on the approach corridor walls."""
    width, height = dims.width, dims.height
    n_pil = int(rng.integers(0, 3))
    for _ in range(n_pil):
        side = 1.0 if rng.random() < 0.5 else -1.0
        x = float(rng.uniform(-dims.la + 0.5, -2.5))
        s = float(rng.uniform(0.25, 0.45))
        dep = float(rng.uniform(0.1, 0.2))
        v, f = box_mesh([x, side * (width / 2 - dep / 2 + 0.05), height / 2], [s, dep + 0.1, height])
        plan.mb.add(v, f, "concrete" if rng.random() < 0.7 else "metal", "pillar")
        plan.feats.append({"kind": "pillar", "center": [round(x, 3), round(side * width / 2, 3)], "size": round(s, 3)})


def _floor_boxes(plan: _Floorplan, dims: _Dims, rng: np.random.Generator) -> None:
    """0-2 boxes on the floor against the approach walls, behind the robot's path end (none where the
    corridor would be left too narrow for the robot)."""
    width = dims.width
    n_box = int(rng.integers(0, 3))
    for _ in range(n_box):
        side = 1.0 if rng.random() < 0.5 else -1.0
        sz = rng.uniform([0.3, 0.3, 0.25], [0.6, 0.5, 0.7])
        if width / 2 - sz[1] < 0.45:
            continue  # corridor too narrow to leave room for the robot
        x = float(rng.uniform(-dims.la + 0.5, -1.5))
        v, f = box_mesh([x, side * (width / 2 - sz[1] / 2 - 0.02), sz[2] / 2], sz, float(rng.uniform(-0.1, 0.1)))
        plan.mb.add(v, f, "cardboard" if rng.random() < 0.6 else "wood", "box")
        plan.feats.append({"kind": "box", "center": [round(x, 3), round(side * width / 2, 3)],
                           "size": np.round(sz, 3).tolist()})


def _shell(plan: _Floorplan, height: float, floor_mat: str, ceil_mat: str) -> None:
    """Walls (one vertical quad per outline edge, normal facing the interior: left of the edge), floor
    at z = 0 and ceiling at ``height`` m over the outline."""
    poly = plan.poly
    P = len(poly)
    for i in range(P):
        a, b = poly[i], poly[(i + 1) % P]
        v = np.array([[a[0], a[1], 0.0], [b[0], b[1], 0.0], [b[0], b[1], height], [a[0], a[1], height]])
        plan.mb.add(v, [[0, 2, 1], [0, 3, 2]], plan.edge_mat[i], plan.edge_cls[i])
    tri = triangulate_polygon(poly)
    fl = np.column_stack([poly, np.zeros(P)])
    plan.mb.add(fl, tri[:, [0, 1, 2]], floor_mat, "floor")           # CCW seen from above: normal +z
    ce = np.column_stack([poly, np.full(P, height)])
    plan.mb.add(ce, tri[:, [0, 2, 1]], ceil_mat, "ceiling")          # normal -z


# ------------------------------------------------------------------ plan-view occlusion
def hidden_from(poly: np.ndarray, viewers: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(T,) bool: True where target point (x,y) is hidden by the outline walls from every viewer.

    ``viewers`` (M,2), ``targets`` (T,2). A segment viewer→target that properly crosses any outline
    edge is occluded (walls are full height, so plan view is exact).
    """
    a = poly
    b = np.roll(poly, -1, axis=0)
    V = np.asarray(viewers, dtype=np.float64)[:, None, None, :]
    T = np.asarray(targets, dtype=np.float64)[None, :, None, :]
    A, B = a[None, None], b[None, None]

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    d1 = cross(B - A, V - A)
    d2 = cross(B - A, T - A)
    d3 = cross(T - V, A - V)
    d4 = cross(T - V, B - V)
    hit = (d1 * d2 < 0) & (d3 * d4 < 0)
    blocked = hit.any(axis=2)  # (M, T)
    return blocked.all(axis=0)
