"""The D2SLAM keypoint classifier behind the engine's hook (``d2slam.slam.hook.KeypointFilter``).

Per frame (``D2SlamFilter.__call__``), reading as the paper's pipeline:

    z            = the engine's robust keypoint depth; beta, alpha, delta, gamma of it        (depth.py)
    P_S, zones   = semantic module on the person masks                                       (eq 1-2, semantic.py)
    P_g, flag    = geometric module on the matches to frame t-1                              (eq 4-6, geometric.py)
                   + the pose test (ours, RGB-D: PnP pose, reprojection and depth residuals)
    P            = eq 7 fusion (+ ours: an unmatched keypoint takes its matched neighbours' P_g
                   when larger; with the flow, an unobserved one just outside a mask is raised to
                   flow_edge_p); bel = eq 8 Bayesian update from bel(q) / the map point       (fusion.py)
    OIM          = static keypoints in a person's interaction zone near geometric-dynamic ones -> dynamic
                   (candidates: not observed static this frame, i.e. not matched with err <= alpha
                   and passing the pose test; our deviation, OursConfig.oim_skip_observed_static)
                                                                                             (eq 9-10, interaction.py)

Variants (the study's ablations; ``d2slam.run.methods`` registers each under its method name, ``none`` being the hook
off): :class:`D2SlamFilter` with its :class:`~d2slam.dynamics.switches.Switches`, or one module alone.

- ``Switches()``  (``d2slam``) the full method.
- ``flow``        (``d2slam-flow``) ours: the full method with sub-pixel correspondences for eq 5 by LK flow
                  (``flow.py``; also ``FlowConfig.enabled`` with any switches). Needs the grey images
                  (``FilterInput.gray`` and ``prev_gray``): without them (first frame, stored features) the frame
                  runs as without the flow plus the edge band.
                  The flow's new matches take their depth from the previous depth image (``FilterInput.prev_depth``,
                  ``FlowConfig.flow_new_depth``), so the pose test runs on them. A keypoint that neither the
                  matches nor the flow observed, within ``flow_edge_band`` px outside a mask, is raised to
                  ``flow_edge_p`` (``fusion.edge_band``; also on frames without images, where nothing is tracked).
- ``depth`` off   (``no-depth``) every depth-adaptive quantity at the midpoint of its range (beta 0.15, alpha 0.7 px,
                  delta 29.5 px, gamma 19 px), the OIM's depth tests dropped (plain centroid), no pose test and no
                  neighbours' P_g for unmatched keypoints (both need depth).
- ``oim`` off     (``no-oim``) without the Object Interaction Module.
- ``bayes`` off   (``no-bayes``) the eq 7 probability P used directly as the belief (no temporal filter, no prior).
- :class:`SemanticFilter` (``semantic``) masks only, DynaSLAM-like: every keypoint inside a mask is dynamic (belief
                  1), every other 0.
- :class:`EpipolarFilter` (``geometric``) epipolar check only with the fixed threshold ``fixed_alpha`` (x 1.2^octave
                  like alpha(z), see ``depth.octave_factor``), no masks, no filter: belief = P_g for matched keypoints
                  (p_g_exceed = 0.7 above the threshold), 0.5 (no observation) for the others.

``last`` holds the diagnostics of the last frame (``FrameDiagnostics``): every module's output and its time, so
per-module precision/recall can be measured (``FrameDiagnostics.predictions``).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from d2slam.data.config import DepthNoise
from d2slam.dynamics import depth as dz
from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.flow import check_flow_area, flow_correspondences, flow_keypoints, flow_matches
from d2slam.dynamics.fusion import bayes_update, check_edge_band, edge_band, fuse, prior_belief
from d2slam.dynamics.geometric import GeometricResult, PoseInputs, check_matches, geometric_module
from d2slam.dynamics.interaction import (MatchedPoints, binomial, mask_depths, moving_masks, neighbour_p_g,
                                         oim_candidates, oim_frame)
from d2slam.dynamics.semantic import FrameMasks, SemanticResult, semantic_module
from d2slam.dynamics.switches import Switches
from d2slam.errors import D2SlamError
from d2slam.ranges import AnyConfig, part_of
from d2slam.slam.frame import undistort as undistort_points
from d2slam.slam.hook import FilterInput
from d2slam.slam.timing import StageTimer


@dataclass
class FrameDiagnostics:
    """Per-module outputs of one frame (N keypoints). Fields of modules a mode does not run are None."""

    frame_index: int
    mode: str  # the method (``d2slam.run.methods``) the filter was built for
    z: np.ndarray  # (N,) keypoint depth used (m, 0 invalid)
    belief: np.ndarray  # (N,) the hook's output
    p_s: np.ndarray | None = None  # eq 2
    inside: np.ndarray | None = None  # inside some mask
    uncertain: np.ndarray | None = None  # in a mask's uncertainty zone
    in_area: np.ndarray | None = None  # inside or uncertain (eq 7's "mask area")
    err: np.ndarray | None = None  # eq 5 (NaN unmatched)
    p_g: np.ndarray | None = None  # eq 6 (NaN unobserved)
    observed: np.ndarray | None = None  # matched with P_g defined
    geo_dynamic: np.ndarray | None = None  # err > alpha, or the pose test's flag
    reproj_err: np.ndarray | None = None  # pose test (ours): reprojection error (px), NaN where not tested
    depth_err: np.ndarray | None = None  # pose test (ours): normalised depth residual, NaN where not tested
    pose_dynamic: np.ndarray | None = None  # the pose test's flag
    widening: tuple[float, float, float] | None = None  # noise widening of eq 5, reprojection, depth (ours)
    edge: np.ndarray | None = None  # ours, with the flow: unobserved just outside a mask, P raised (fusion.edge_band)
    silhouette: np.ndarray | None = None  # ours: corner on a person's outline, P raised (OursConfig.silhouette_px)
    fused: np.ndarray | None = None  # eq 7 P
    prior: np.ndarray | None = None  # eq 8 bel(q)
    belief_bayes: np.ndarray | None = None  # eq 8 bel before the OIM
    zone: np.ndarray | None = None  # in an interaction zone (eq 9); only tested where eq 10's centroid test passes
    oim: np.ndarray | None = None  # turned dynamic by the OIM (eq 10)
    mask_depth: np.ndarray | None = None  # (n,) z_n
    f_found: bool = False
    f_matches: int = 0  # matches given to RANSAC
    f_static_only: bool = False
    timings_ms: dict[str, float] = field(default_factory=dict)

    def predictions(self, threshold: float = 0.5) -> dict[str, np.ndarray]:
        """Boolean "dynamic" prediction of each module that ran: semantic (P_S > 0.5, i.e. inside a mask),
        geometric (err > alpha or the pose test), pose (the pose test alone), edge (flagged by
        ``fusion.edge_band``, with the flow), silhouette (``OursConfig.silhouette_px``), fusion (eq 7 P > 0.5), bayes
        (eq 8 belief > 0.5 before the OIM), oim (flipped by the OIM), final (the hook's belief > 0.5)."""
        out: dict[str, np.ndarray] = {}
        if self.p_s is not None:
            out["semantic"] = self.p_s > threshold
        if self.geo_dynamic is not None:
            out["geometric"] = self.geo_dynamic.copy()
        if self.pose_dynamic is not None:
            out["pose"] = self.pose_dynamic.copy()
        if self.edge is not None:
            out["edge"] = self.edge.copy()
        if self.silhouette is not None:
            out["silhouette"] = self.silhouette.copy()
        if self.fused is not None:
            out["fusion"] = self.fused > threshold
        if self.belief_bayes is not None:
            out["bayes"] = self.belief_bayes > threshold
        if self.oim is not None:
            out["oim"] = self.oim.copy()
        out["final"] = self.belief > threshold
        return out


def _check_input(inp: FilterInput) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    kps = np.asarray(inp.kps, dtype=np.float64)
    if kps.size == 0:
        kps = kps.reshape(0, 2)
    if kps.ndim != 2 or kps.shape[1] != 2:
        raise D2SlamError(f"frame {inp.frame_index}: keypoints must be (N, 2), got shape {kps.shape}")
    n = len(kps)
    if inp.kps_px is not None and np.shape(inp.kps_px) != (n, 2):
        raise D2SlamError(f"frame {inp.frame_index}: kps_px has shape {np.shape(inp.kps_px)} for {n} keypoints")
    z = np.asarray(inp.kp_depth, dtype=np.float64).reshape(-1)
    if len(z) != n:
        raise D2SlamError(f"frame {inp.frame_index}: kp_depth has {len(z)} entries for {n} keypoints")
    masks = inp.masks
    if masks is not None:
        masks = np.asarray(masks)
        shape = np.asarray(inp.depth).shape
        if masks.ndim != 3 or masks.shape[1:] != shape:
            raise D2SlamError(f"frame {inp.frame_index}: person masks must be (n, {shape[0]}, {shape[1]}) "
                              f"like the depth image, got shape {masks.shape}")
        if masks.dtype != bool:
            masks = masks != 0
    return kps, z, masks


def _ms(timer: StageTimer) -> dict[str, float]:
    """The stage timings of one frame in milliseconds, with their ``total``."""
    t = {k: v * 1e3 for k, v in timer.seconds.items()}
    t["total"] = sum(t.values())
    return t


@dataclass
class Previous:
    """The previous frame's keypoints as eq 4-6 compare against (the input's, or the flow's: ``flow.flow_matches``):
    positions (undistorted; ``px`` where they are in the image), robust depths, beliefs, the matches (K, 2) to them
    and which of these F may be fitted on (None: all)."""

    kps: np.ndarray
    depth: np.ndarray
    belief: np.ndarray
    matches: np.ndarray
    fit: np.ndarray | None
    px: np.ndarray

    @classmethod
    def of(cls, inp: FilterInput) -> "Previous":
        return cls(inp.prev_kps, inp.prev_kp_depth, inp.prev_belief, inp.matches, None, inp.pixels()[1])


@dataclass
class FrameState:
    """What one frame's modules computed, as the later ones read it: the keypoints where they are in the images
    (``px``), their depth maps (eq 2, 5, 9, 10), the masks seen from them with the widest uncertainty zone searched
    (``margin``) and each mask's depth (``z_n``, eq 9), the semantic and geometric modules' results, the matched
    keypoints (shared by the neighbours' P_g and the OIM) and those neighbours' P_g (ours; None when off)."""

    px: np.ndarray
    maps: dz.DepthMaps
    masks: FrameMasks
    margin: float
    z_n: np.ndarray
    sem: SemanticResult | None = None
    geo: GeometricResult | None = None
    matched: MatchedPoints | None = None
    p_nb: np.ndarray | None = None
    silhouette: np.ndarray | float = 0.0  # the silhouette band's width at each keypoint (px; ours; 0: off)


class D2SlamFilter:
    """D2SLAM's dynamic-keypoint classifier (eq 1-10) with its ablation ``switches``; implements the
    ``KeypointFilter`` protocol. ``name``: the method it runs for (the diagnostics' ``mode``)."""

    def __init__(self, config: AnyConfig | DynamicsConfig | None = None, switches: Switches = Switches(),
                 name: str = "d2slam"):
        self.cfg = part_of(config, "dynamics", DynamicsConfig)
        self.switches, self.mode = switches, name
        self.use_flow = switches.flow or self.cfg.flow.enabled
        if self.use_flow:
            check_flow_area(self.cfg.flow.flow_area)
            check_edge_band(self.cfg.flow.flow_edge_band, self.cfg.flow.flow_edge_p)
        self.last: FrameDiagnostics | None = None
        self._pnp: ThreadPoolExecutor | None = None  # the pose test's PnP while F is fitted (``_geometric``)
        if switches.oim and self.cfg.ours.oim_moving_test:
            binomial()  # imported now, before a run's first frame

    def reset(self) -> None:
        self.last = None

    def __call__(self, inp: FilterInput) -> np.ndarray:
        cfg, on = self.cfg, self.switches
        kps, z, masks = _check_input(inp)
        px = np.asarray(inp.pixels()[0], dtype=np.float64).reshape(-1, 2)  # in the images: masks, depth, flow
        n = len(kps)
        timer = StageTimer()
        with timer("depth_maps"):  # beta, alpha, delta, gamma of every keypoint, once (eq 2, 5, 9, 10)
            maps = dz.DepthMaps(z, cfg, on.depth)
            scale = dz.octave_factor(inp.octave, n, inp.scale_factor, cfg.ours.alpha_at_scale)  # eq 5 at each scale
        with timer("mask_edges_depth"):
            f = self._masks(inp, px, masks, maps)
        if cfg.ours.silhouette_px > 0:  # the silhouette band's width at each keypoint's scale (ours)
            f.silhouette = cfg.ours.silhouette_px * dz.octave_factor(inp.octave, n, inp.scale_factor)
        with timer("semantic"):  # eq 1-2; exact at least as far as the edge bands (the flow's, the silhouette's)
            band = max(cfg.flow.flow_edge_band if self.use_flow else 0.0, float(np.max(f.silhouette, initial=0.0)))
            f.sem = semantic_module(f.masks, px, maps.beta, max(f.margin, band), cfg)
        prev = Previous.of(inp)
        if self.use_flow and inp.gray is not None and inp.prev_gray is not None and n:
            with timer("flow"):
                prev, scale = self._flow(inp, px, f.sem.in_area, scale)
        with timer("geometric"):  # eq 4-6 and the pose test
            f.geo = self._geometric(inp, kps, z, maps.alpha, scale, prev)
        with timer("fusion"):  # eq 7
            p, edge, silhouette = self._fusion(f)
        with timer("bayes"):  # eq 8
            prior = prior_belief(n, inp.matches, inp.prev_belief, inp.mappoint_belief, cfg) if on.bayes else None
            bel = bayes_update(prior, p, cfg) if on.bayes else p.copy()
        with timer("oim"):  # eq 9-10
            zone, oim = self._oim(f, bel)
            belief = np.where(oim, np.maximum(bel, cfg.ours.oim_belief), bel) if on.oim else bel
        self.last = FrameDiagnostics(inp.frame_index, self.mode, z, belief, **_semantic_fields(f.sem),
                                     **_geometric_fields(f.geo), edge=edge, silhouette=silhouette, fused=p, prior=prior,
                                     belief_bayes=bel, zone=zone, oim=oim, mask_depth=f.z_n, timings_ms=_ms(timer))
        return belief

    def _masks(self, inp: FilterInput, px: np.ndarray, masks, maps) -> FrameState:
        """The frame's state with the masks seen from the keypoints (edges, pixel lookups, bounding-box distances),
        shared by the semantic module and the OIM; the widest uncertainty zone (how far signed distances are
        searched: the OIM extends them later, only where it needs to) and each mask's depth z_n (eq 9-10; NaN without
        the OIM)."""
        fm = FrameMasks(masks, px, np.shape(inp.depth))
        margin = float(dz.uncertainty_width(maps.beta.min(), self.cfg)) + 1.0 if len(px) else 0.0
        z_n = mask_depths(inp.depth, fm, self.cfg) if self.switches.oim else np.full(len(fm.edges), np.nan)
        return FrameState(px, maps, fm, margin, z_n)

    def _flow(self, inp: FilterInput, px: np.ndarray, in_area: np.ndarray, scale) -> tuple[Previous, np.ndarray]:
        """Ours: sub-pixel correspondences by LK flow (flow.py) in place of the matches, and the threshold scale
        (alpha and sigma unscaled where the flow tracked). The flow runs in the images (``px``, the keypoints where
        they are in them); its tracks are undistorted for eq 5."""
        cfg = self.cfg
        m0 = check_matches(inp.matches, len(px), len(inp.prev_kps))
        q_px = flow_correspondences(inp.gray, inp.prev_gray, px, inp.pixels()[1], m0, cfg,
                                    track=flow_keypoints(in_area, m0, cfg.flow.flow_area))
        args = (inp.prev_kp_depth, inp.prev_belief, m0, inp.prev_depth, cfg)
        kw = dict(shape=np.shape(inp.gray), radius=inp.depth_patch_radius)
        if inp.kps_px is None:
            *prev, tracked = flow_matches(q_px, inp.prev_kps, *args, **kw)
            prev_px = prev[0]
        else:  # the same matches twice: undistorted for geometry, in the image for the depth
            q = undistort_points(q_px, inp.camera)
            *prev, tracked = flow_matches(q, inp.prev_kps, *args, q_px=q_px, **kw)
            prev_px = flow_matches(q_px, inp.pixels()[1], *args, **kw)[0]
        return Previous(*prev, prev_px), np.where(tracked, 1.0, scale)

    def _geometric(self, inp: FilterInput, kps: np.ndarray, z: np.ndarray, alpha: np.ndarray, scale,
                   prev: Previous) -> GeometricResult:
        """Eq 4-6 against the previous frame's keypoints ``prev``, with the pose test (ours) when the depths are used,
        which skips the depths read across a depth edge (ours, ``PoseTestConfig.depth_edge_skip``)."""
        cfg = self.cfg
        pose = None
        if self.switches.depth and cfg.pose_test.enabled:  # the pose test needs the depths
            noise = inp.camera.depth_noise if inp.camera is not None else DepthNoise()
            pose = PoseInputs(z, prev.depth, inp.K, noise)
            if cfg.pose_test.depth_edge_skip and inp.prev_depth is not None:
                r = inp.depth_patch_radius
                pose.depth_edge = dz.depth_edge(inp.depth, inp.pixels()[0], z, cfg, r, noise)
                pose.prev_depth_edge = dz.depth_edge(inp.prev_depth, prev.px, prev.depth, cfg, r, noise)
            if self._pnp is None:  # one thread per filter, stopped when the filter is garbage-collected
                self._pnp = ThreadPoolExecutor(max_workers=1, thread_name_prefix="d2slam-pnp")
        return geometric_module(kps, prev.kps, prev.matches, prev.belief, alpha * scale, cfg, seed=inp.seed,
                                scale=scale, fit=prev.fit, pose=pose, executor=self._pnp)

    def _fusion(self, f: FrameState) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """Eq 7: (P, the edge band's flags (ours, with the flow) or None, the silhouette band's (ours,
        ``OursConfig.silhouette_px``) or None); sets the frame's matched keypoints and their P_g for unmatched
        neighbours (ours), shared with the OIM (eq 9's dynamic neighbours are matched keypoints)."""
        cfg, ud, sem, geo = self.cfg, self.switches.depth, f.sem, f.geo
        f.matched = MatchedPoints(f.px, geo.observed, f.masks.kp.finite, f.maps.valid if ud else None)
        if ud and cfg.ours.neighbour_p_g:  # an unmatched keypoint's matched neighbours (not inside masks: P_S > 0.5)
            f.p_nb = neighbour_p_g(f.px, f.maps, geo.observed, geo.p_g, cfg, skip=sem.inside, matched=f.matched)
        p = fuse(sem.p_s, geo.p_g, geo.observed, sem.in_area, sem.uncertain, cfg, f.p_nb)
        edge = None
        if self.use_flow:  # unobserved keypoints just outside a mask (fusion.edge_band)
            p, edge = edge_band(p, sem.d_max, geo.observed, cfg.flow.flow_edge_band, cfg.flow.flow_edge_p)
        silhouette = None
        if cfg.ours.silhouette_px > 0:  # keypoints whose corner is a person's outline, matched or not
            p, silhouette = edge_band(p, sem.d_max, None, f.silhouette, cfg.ours.silhouette_p)
        return p, edge, silhouette

    def _oim(self, f: FrameState, bel: np.ndarray):
        """Eq 9-10: (in an interaction zone, turned dynamic), both None without the OIM. Eq 10's centroid test
        first, on the static keypoints near a mask, then the zone test (eq 9) only where it would flip: the same
        result as testing the zone first, with far fewer edge searches."""
        if not self.switches.oim:
            return None, None
        cand = oim_candidates(bel, f.geo.observed, f.geo.dynamic, self.cfg, f.p_nb)
        moving = moving_masks(f.masks, f.geo.observed, f.geo.dynamic, self.cfg)
        return oim_frame(f.masks, f.px, f.maps, f.z_n, f.sem.d, f.margin, cand, f.geo.dynamic, self.cfg,
                         self.switches.depth, f.matched, moving)


def _semantic_fields(sem) -> dict:
    """The semantic module's outputs as ``FrameDiagnostics`` fields."""
    return dict(p_s=sem.p_s, inside=sem.inside, uncertain=sem.uncertain, in_area=sem.in_area)


def _geometric_fields(geo: GeometricResult) -> dict:
    """The geometric module's outputs (with the pose test's) as ``FrameDiagnostics`` fields."""
    return dict(err=geo.err, p_g=geo.p_g, observed=geo.observed, geo_dynamic=geo.dynamic, reproj_err=geo.reproj_err,
                depth_err=geo.depth_err, pose_dynamic=geo.pose_dynamic, widening=geo.widening,
                f_found=geo.F is not None, f_matches=geo.n_used, f_static_only=geo.used_static)


class _OneModule:
    """A baseline filter that runs one module of the paper alone (no fusion, no temporal filter): ``_module``
    gives the beliefs and the module's diagnostics, timed as ``stage``."""

    stage = ""

    def __init__(self, config: AnyConfig | DynamicsConfig | None = None, name: str = ""):
        self.cfg, self.mode = part_of(config, "dynamics", DynamicsConfig), name or self.stage
        self.last: FrameDiagnostics | None = None

    def reset(self) -> None:
        self.last = None

    def __call__(self, inp: FilterInput) -> np.ndarray:
        kps, z, masks = _check_input(inp)
        timer = StageTimer()
        with timer(self.stage):
            belief, found = self._module(inp, kps, z, masks)
        self.last = FrameDiagnostics(inp.frame_index, self.mode, z, belief, timings_ms=_ms(timer), **found)
        return belief


class SemanticFilter(_OneModule):
    """The ``semantic`` baseline: masks only, DynaSLAM-like (eq 1-2's "inside a mask" alone)."""

    stage = "semantic"

    def _module(self, inp: FilterInput, kps: np.ndarray, z: np.ndarray, masks):
        b = dz.beta(z, self.cfg)
        margin = float(dz.uncertainty_width(b.min(), self.cfg)) + 1.0 if len(kps) else 0.0
        sem = semantic_module(masks, np.asarray(inp.pixels()[0], dtype=np.float64).reshape(-1, 2), b, margin, self.cfg)
        return sem.inside.astype(np.float64), _semantic_fields(sem)


class EpipolarFilter(_OneModule):
    """The ``geometric`` baseline: the epipolar check alone (eq 4-6) with the fixed threshold ``fixed_alpha`` at each
    keypoint's detection scale; no masks, no filter."""

    stage = "geometric"

    def _module(self, inp: FilterInput, kps: np.ndarray, z: np.ndarray, masks):
        cfg = self.cfg
        scale = dz.octave_factor(inp.octave, len(kps), inp.scale_factor, cfg.ours.alpha_at_scale)
        geo = geometric_module(kps, inp.prev_kps, inp.matches, inp.prev_belief, cfg.fixed_alpha * scale, cfg,
                               seed=inp.seed, scale=scale)  # threshold and sigma at the detection scale
        belief = np.where(geo.observed, np.nan_to_num(geo.p_g), cfg.p_no_observation)
        return belief, _geometric_fields(geo)
