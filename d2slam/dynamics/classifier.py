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
                   and passing the pose test; our deviation, DynamicsConfig.oim_skip_observed_static)
                                                                                             (eq 9-10, interaction.py)

Modes (the ablations of the study; ``get_filter(method, config)`` builds one, ``none`` -> None, the hook off):

- ``d2slam``    the full method.
- ``d2slam-flow`` ours: the full method with sub-pixel correspondences for eq 5 by LK flow (``flow.py``; also
                ``DynamicsConfig.flow`` in the other full-method modes). Needs the grey images (``FilterInput.gray``
                and ``prev_gray``): without them (first frame, stored features) the frame runs as ``d2slam`` plus
                the edge band.
                The flow's new matches take their depth from the previous depth image (``FilterInput.prev_depth``,
                ``DynamicsConfig.flow_new_depth``), so the pose test runs on them. A keypoint that neither the
                matches nor the flow observed, within ``flow_edge_band`` px outside a mask, is raised to
                ``flow_edge_p`` (``fusion.edge_band``; also on frames without images, where nothing is tracked).
- ``no-depth``  every depth-adaptive quantity at the midpoint of its range (beta 0.15, alpha 0.7 px, delta 29.5 px,
                gamma 19 px), the OIM's depth tests dropped (plain centroid), no pose test and no neighbours' P_g
                for unmatched keypoints (both need depth).
- ``no-oim``    without the Object Interaction Module.
- ``no-bayes``  the eq 7 probability P used directly as the belief (no temporal filter, no prior).
- ``semantic``  masks only, DynaSLAM-like: every keypoint inside a mask is dynamic (belief 1), every other 0.
- ``geometric`` epipolar check only with the fixed threshold ``fixed_alpha`` (x 1.2^octave like alpha(z), see
                ``depth.octave_factor``), no masks, no filter: belief = P_g
                for matched keypoints (p_g_exceed = 0.7 above the threshold), 0.5 (no observation) for the others.

``last`` holds the diagnostics of the last frame (``FrameDiagnostics``): every module's output and its time, so
per-module precision/recall can be measured (``FrameDiagnostics.predictions``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from d2slam.config import Config, DynamicsConfig
from d2slam.dynamics import METHODS, MODES, NEEDS_MASKS, register_methods  # noqa: F401 (names defined there, light)
from d2slam.dynamics import depth as dz
from d2slam.dynamics.fusion import bayes_update, check_edge_band, edge_band, fuse, prior_belief
from d2slam.dynamics.flow import check_flow_area, flow_correspondences, flow_keypoints, flow_matches
from d2slam.dynamics.geometric import check_matches, geometric_module
from d2slam.dynamics.interaction import MatchedPoints, mask_depths, neighbour_p_g, oim_candidates, oim_frame
from d2slam.dynamics.semantic import FrameMasks, semantic_module
from d2slam.errors import D2SlamError
from d2slam.slam.hook import FilterInput


@dataclass
class FrameDiagnostics:
    """Per-module outputs of one frame (N keypoints). Fields of modules a mode does not run are None."""

    frame_index: int
    mode: str
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
    edge: np.ndarray | None = None  # ours, with the flow: unobserved just outside a mask, P raised (fusion.edge_band)
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
        ``fusion.edge_band``, with the flow), fusion (eq 7 P > 0.5), bayes (eq 8
        belief > 0.5 before the OIM), oim (flipped by the OIM), final (the hook's belief > 0.5)."""
        out: dict[str, np.ndarray] = {}
        if self.p_s is not None:
            out["semantic"] = self.p_s > threshold
        if self.geo_dynamic is not None:
            out["geometric"] = self.geo_dynamic.copy()
        if self.pose_dynamic is not None:
            out["pose"] = self.pose_dynamic.copy()
        if self.edge is not None:
            out["edge"] = self.edge.copy()
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


class D2SlamFilter:
    """D2SLAM's dynamic-keypoint classifier for one mode; implements the ``KeypointFilter`` protocol."""

    def __init__(self, config: Config | DynamicsConfig | None = None, mode: str = "d2slam"):
        if mode not in MODES:
            raise D2SlamError(f"unknown dynamics method {mode!r}; choose one of {', '.join(METHODS)}")
        if config is None:
            config = DynamicsConfig()
        self.cfg: DynamicsConfig = config.dynamics if isinstance(config, Config) else config
        self.mode = mode
        self.use_depth = mode != "no-depth"
        self.use_oim = mode in ("d2slam", "d2slam-flow", "no-depth", "no-bayes")
        self.use_bayes = mode in ("d2slam", "d2slam-flow", "no-depth", "no-oim")
        self.use_flow = self.cfg.flow or mode == "d2slam-flow"
        if self.use_flow:
            check_flow_area(self.cfg.flow_area)
            check_edge_band(self.cfg.flow_edge_band, self.cfg.flow_edge_p)
        self.last: FrameDiagnostics | None = None

    def reset(self) -> None:
        self.last = None

    def __call__(self, inp: FilterInput) -> np.ndarray:
        cfg, mode = self.cfg, self.mode
        kps, z, masks = _check_input(inp)
        n = len(kps)
        t = {}
        clock = time.perf_counter
        t0 = clock()

        if mode == "semantic":
            b = dz.beta(z, cfg)
            margin = float(dz.uncertainty_width(b.min(), cfg)) + 1.0 if n else 0.0
            sem = semantic_module(masks, kps, b, margin, cfg)
            belief = sem.inside.astype(np.float64)
            t["semantic"] = (clock() - t0) * 1e3
            t["total"] = sum(t.values())
            self.last = FrameDiagnostics(inp.frame_index, mode, z, belief, p_s=sem.p_s, inside=sem.inside,
                                         uncertain=sem.uncertain, in_area=sem.in_area, timings_ms=t)
            return belief

        if mode == "geometric":
            scale = dz.octave_factor(getattr(inp, "octave", None), n, cfg)
            geo = geometric_module(kps, inp.prev_kps, inp.matches, inp.prev_belief, cfg.fixed_alpha * scale, cfg,
                                   scale=scale)  # threshold and sigma at the detection scale
            belief = np.where(geo.observed, np.nan_to_num(geo.p_g), cfg.p_no_observation)
            t["geometric"] = (clock() - t0) * 1e3
            t["total"] = sum(t.values())
            self.last = FrameDiagnostics(inp.frame_index, mode, z, belief, err=geo.err, p_g=geo.p_g,
                                         observed=geo.observed, geo_dynamic=geo.dynamic, f_found=geo.F is not None,
                                         f_matches=geo.n_used, f_static_only=geo.used_static, timings_ms=t)
            return belief

        # Full method and its ablations.
        ud = self.use_depth
        maps = dz.DepthMaps(z, cfg, ud)  # beta, alpha, delta, gamma of every keypoint, once
        # eq 5 threshold at each keypoint's detection scale (alpha(z) * 1.2^octave, see depth.octave_factor).
        scale = dz.octave_factor(getattr(inp, "octave", None), n, cfg)
        b, a = maps.beta, maps.alpha * scale
        t1 = clock()
        t["depth_maps"] = (t1 - t0) * 1e3
        # The masks seen from the keypoints (edges, pixel lookups, bounding-box distances), shared by the semantic
        # module and the OIM. Signed distances are searched as far as the widest uncertainty zone (the OIM extends
        # them later, only where it needs to).
        fm = FrameMasks(masks, kps, np.shape(inp.depth))
        margin = float(dz.uncertainty_width(b.min(), cfg)) + 1.0 if n else 0.0
        z_n = mask_depths(inp.depth, fm, cfg) if self.use_oim else np.full(len(fm.edges), np.nan)
        t2 = clock()
        t["mask_edges_depth"] = (t2 - t1) * 1e3
        # With the flow, eq 1 is exact at least as far as the edge band (fusion.edge_band reads d_max within it).
        band = cfg.flow_edge_band if self.use_flow else 0.0
        sem = semantic_module(fm, kps, b, max(margin, band), cfg)
        t3 = clock()
        t["semantic"] = (t3 - t2) * 1e3
        pose = ud and cfg.pose_test  # the pose test needs the depths (off in no-depth)
        prev_kps, prev_z, prev_bel, matches, fit = inp.prev_kps, inp.prev_kp_depth, inp.prev_belief, inp.matches, None
        if self.use_flow and inp.gray is not None and getattr(inp, "prev_gray", None) is not None and n:
            # ours: sub-pixel correspondences by LK flow (flow.py); alpha and sigma unscaled where the flow tracked
            m0 = check_matches(matches, n, len(prev_kps))
            q = flow_correspondences(inp.gray, inp.prev_gray, kps, prev_kps, m0, cfg,
                                     track=flow_keypoints(sem.in_area, m0, cfg.flow_area))
            prev_kps, prev_z, prev_bel, matches, fit, tracked = flow_matches(
                q, prev_kps, prev_z, prev_bel, m0, getattr(inp, "prev_depth", None), cfg, shape=np.shape(inp.gray))
            scale = np.where(tracked, 1.0, scale)
            a = maps.alpha * scale
            t3b = clock()
            t["flow"] = (t3b - t3) * 1e3
            t3 = t3b
        geo = geometric_module(kps, prev_kps, matches, prev_bel, a, cfg, scale=scale,
                               kp_depth=z if pose else None, prev_kp_depth=prev_z if pose else None,
                               K=inp.K if pose else None, fit=fit)
        t4 = clock()
        t["geometric"] = (t4 - t3) * 1e3
        # The matched keypoints and their k-d tree, shared by the neighbours' P_g and the OIM (eq 9's dynamic
        # neighbours are matched keypoints); the tree is built on first use.
        matched = MatchedPoints(kps, geo.observed, fm.kp.finite, maps.valid if ud else None)
        p_nb = None  # ours: an unmatched keypoint's matched neighbours (skipped inside masks, where P_S > 0.5)
        if ud and cfg.neighbour_p_g:
            p_nb = neighbour_p_g(kps, maps, geo.observed, geo.p_g, cfg, skip=sem.inside, matched=matched)
        p = fuse(sem.p_s, geo.p_g, geo.observed, sem.in_area, sem.uncertain, cfg, p_nb)
        edge = None
        if self.use_flow:  # ours: unobserved keypoints just outside a mask (fusion.edge_band)
            p, edge = edge_band(p, sem.d_max, geo.observed, cfg.flow_edge_band, cfg.flow_edge_p)
        t5 = clock()
        t["fusion"] = (t5 - t4) * 1e3
        prior = None
        if self.use_bayes:
            prior = prior_belief(n, inp.matches, inp.prev_belief, inp.mappoint_belief, cfg)
            bel = bayes_update(prior, p, cfg)
        else:
            bel = p.copy()
        t6 = clock()
        t["bayes"] = (t6 - t5) * 1e3
        belief, zone, oim = bel, None, None
        if self.use_oim:
            # eq 10's centroid test first, on the static keypoints near a mask, then the zone test (eq 9) only where
            # it would flip: the same result as testing the zone first, with far fewer edge searches.
            cand = oim_candidates(bel, geo.observed, geo.dynamic, cfg, p_nb)
            zone, oim = oim_frame(fm, kps, maps, z_n, sem.d, margin, cand, geo.dynamic, cfg, ud, matched)
            belief = np.where(oim, np.maximum(bel, cfg.oim_belief), bel)
        t["oim"] = (clock() - t6) * 1e3
        t["total"] = sum(t.values())
        self.last = FrameDiagnostics(
            inp.frame_index, mode, z, belief, p_s=sem.p_s, inside=sem.inside, uncertain=sem.uncertain,
            in_area=sem.in_area, err=geo.err, p_g=geo.p_g, observed=geo.observed, geo_dynamic=geo.dynamic,
            reproj_err=geo.reproj_err, depth_err=geo.depth_err, pose_dynamic=geo.pose_dynamic, edge=edge, fused=p,
            prior=prior, belief_bayes=bel, zone=zone, oim=oim, mask_depth=z_n,
            f_found=geo.F is not None, f_matches=geo.n_used, f_static_only=geo.used_static, timings_ms=t)
        return belief


def get_filter(method: str, config: Config | DynamicsConfig | None = None) -> D2SlamFilter | None:
    """The keypoint filter of a method name (``METHODS``); ``none`` -> None (the engine runs with the hook off)."""
    if method == "none":
        return None
    return D2SlamFilter(config, method)
