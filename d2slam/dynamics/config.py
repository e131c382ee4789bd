"""The paper's modules' constants (``DynamicsConfig``), each with its equation number, and ours beside them
(docs/design.md#depth-adaptive-quantities-eq-2-5-9-10 and the sections after it; docs/deviations.md)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from d2slam.ranges import Checked, below, flag, flat_fields, one_of, section, within


@dataclass(frozen=True)
class OursConfig(Checked):
    """Our deviations inside the paper's modules (each measured: docs/deviations.md), beside the paper's constants
    (``DynamicsConfig``)."""

    _RULES = (below("neighbour_min", "neighbour_k", strict=False),)
    # eq 5 (ours): alpha is expressed at the keypoint's detection scale, alpha(z) * s^octave with s the engine's
    # pyramid scale (OrbConfig.scale_factor, which the hook's input carries: ORB-SLAM's per-level sigma). False, or
    # no octaves from the engine = the paper as printed. Measured: docs/deviations.md.
    alpha_at_scale: bool = flag(True)
    # eq 6 (ours): sigma at the keypoint's detection scale too, sigma x s^octave, like alpha (False = the paper), so
    # that a coarse-level match within its scaled alpha does not get P_g > 0.5. Measured: docs/deviations.md.
    sigma_at_scale: bool = flag(True)
    # eq 5 (ours): P_g of a keypoint whose error exceeds alpha; the paper: 1 (certainly dynamic). 0.7 is the
    # reliability of the test, P(dynamic | err > alpha) with equal priors = r_dyn / (r_dyn + r_static) (measured:
    # docs/deviations.md). See geometric.geometric_probability.
    p_g_exceed: float = within(0.7, 0.0, 1.0)
    # eq 7 (ours): a keypoint with no observation (not matched) takes the mean P_g of its matched neighbours
    # when that is larger than its eq 7 P: of its neighbour_k nearest matched keypoints, those within delta(z) px
    # (eq 9's radius) and neighbour_depth metres, at least neighbour_min of them. False = the paper. See
    # interaction.neighbour_p_g; off: on real frames it spread the false alarms of eq 5 to the unmatched keypoints
    # (measured: docs/deviations.md).
    neighbour_p_g: bool = flag(False)
    neighbour_k: int = within(8, 1, 1000)
    neighbour_depth: float = within(0.15, 0.0, 20.0)
    neighbour_min: int = within(2, 1, 1000)
    # eq 8 (ours): the likelihood P is clipped to [c, 1 - c] so that one observation of exactly 0 or 1 does not erase
    # the prior (bel would be exactly P whatever bel(q) was).
    likelihood_clip: float = within(1e-3, 0.0, 0.5, hi_open=True)
    # eq 7 (ours, 0 = off): a keypoint outside every mask whose corner test, at the keypoint's detection scale,
    # reaches a mask (eq 1's signed distance d in (-silhouette_px x s^octave, 0), s the engine's pyramid scale; FAST's
    # circle has a radius of 3 px at its level) sits on a person's outline: its corner is made by the outline and
    # moves with it, and its descriptor and depth patch see the person, while its centre, the pixel eq 1 reads, is
    # background. It gets P = max(P, silhouette_p) whether it was matched or not (fusion.edge_band): a slowly moving
    # outline passes eq 5 as static. Off: it helped on the development seeds its width was chosen on and not on others
    # (the oracle loses to them, d2slam's wider masks and uncertainty zone already take most). Measured:
    # docs/deviations.md.
    silhouette_px: float = within(0.0, 0.0, 100.0)
    silhouette_p: float = within(0.9, 0.0, 1.0)
    # eq 9 (ours): z_n = median of the valid depths of mask n sampled on a grid of this stride (1 = every pixel),
    # for speed (measured: docs/deviations.md).
    zone_median_stride: int = within(4, 1, 64)
    # eq 10 (ours): belief given to a static keypoint the OIM turns dynamic (the paper only says "becomes dynamic").
    oim_belief: float = within(0.9, 0.0, 1.0)
    # eq 10 (ours): a keypoint whose own epipolar test passed this frame (matched, err <= alpha) is no OIM
    # candidate: its direct evidence of being static is not overridden by its neighbours'. False = the paper's reading
    # (every keypoint still static after eq 8). See interaction.oim_candidates; measured: docs/deviations.md.
    oim_skip_observed_static: bool = flag(True)
    # eq 10 (ours, off): an unmatched keypoint whose matched neighbours say static (their mean P_g <= 0.5, see
    # neighbour_p_g) is no OIM candidate either. Off because it lowers the recall at a given static precision, the
    # keypoint target (docs/deviations.md).
    oim_skip_neighbour_static: bool = flag(False)
    # eq 9 (ours): a person's interaction zone exists only while the person moves: more of the matched keypoints on
    # its mask fail the geometric test (eq 5 or the pose test) than the thresholds' false alarms explain, a one-sided
    # binomial test at oim_moving_alpha with the false-alarm rate 1 - noise_confidence. A still person (seated behind
    # a desk) moves no object, and each false alarm near it would otherwise turn its neighbours dynamic. A mask with
    # fewer than oim_moving_min matched keypoints cannot be told still and keeps its zone. False = the paper's OIM
    # (every person). See interaction.moving_masks; measured: docs/deviations.md.
    oim_moving_test: bool = flag(True)
    oim_moving_alpha: float = within(0.01, 0.0, 1.0, lo_open=True, hi_open=True)
    oim_moving_min: int = within(5, 1, 100_000)
    # eq 5-6 and the pose test (ours): each threshold is widened, frame by frame, to at least the noise_confidence
    # quantile of the frame's static residuals (a chi distribution fitted to their median; geometric.widening):
    # alpha(z) (0.5-0.9 px) sits at the noise floor of a sharp sensor whose depth and colour are taken at one instant,
    # and a real Kinect's static residuals are wider and vary with the motion (blur, the depth image's own capture
    # time). False = the paper's fixed thresholds. Measured: docs/real_data.md, docs/deviations.md.
    noise_widening: bool = flag(True)
    noise_confidence: float = within(0.95, 0.5, 1.0, lo_open=True, hi_open=True, why="a quantile above the median")


@dataclass(frozen=True)
class PoseTestConfig(Checked):
    """The pose test (ours, RGB-D) beside eq 5's epipolar error (``geometric.pose_test``)."""

    # eq 5 (ours, RGB-D): the pose test beside the epipolar error. The epipolar error cannot see motion
    # along the epipolar line (an object carried away from a rotating camera). With depth, the previous 3-D point is
    # moved by the relative pose (PnP-RANSAC on the static-believed matches) and compared with its match: dynamic when
    # the reprojection error exceeds pose_reproj_px x 1.2^octave, or the depth residual
    # |z_p - z_pred| / sqrt(sigma(z_p)^2 + sigma(z_pred)^2) exceeds pose_depth_sigmas (sigma(z): the camera's depth
    # noise, Camera.depth_noise); then P_g = max(P_g, p_pose_exceed). 0 turns a test off. See geometric.pose_residuals;
    # measured: docs/deviations.md.
    enabled: bool = flag(True)
    pose_reproj_px: float = within(4.0, 0.0, 1000.0)
    pose_depth_sigmas: float = within(2.0, 0.0, 1000.0)
    # The depth residual is not tested where the keypoint's depth patch (the engine's, OrbConfig.depth_patch_radius)
    # spans a depth edge: its range above the noise_confidence quantile of the range of that many samples of sigma(z).
    # Such a depth is not the keypoint's surface: on a real Kinect the depth image is taken at its own instant, so
    # under motion an edge's far side is read at the near side's corner (measured: docs/real_data.md). False = every
    # match tested.
    depth_edge_skip: bool = flag(True)
    # P(dynamic | a pose test exceeded) with equal priors, like p_g_exceed (measured: docs/deviations.md).
    p_pose_exceed: float = within(0.9, 0.0, 1.0)
    # Relative pose of the pose test: cv2.solvePnPRansac with SQPnP (seeded with the run's seed, FilterInput.seed;
    # OpenCV re-estimates the pose on the inliers; no further Levenberg-Marquardt refinement: docs/deviations.md).
    pnp_min_matches: int = within(12, 4, 100_000)
    pnp_ransac_px: float = within(2.0, 0.0, 1000.0, lo_open=True)
    pnp_iterations: int = within(50, 1, 1_000_000)
    pnp_confidence: float = within(0.99, 0.0, 1.0, lo_open=True, hi_open=True)


@dataclass(frozen=True)
class FlowConfig(Checked):
    """Sub-pixel correspondences by Lucas-Kanade flow for eq 4-6 (ours; ``flow.py``, the ``d2slam-flow`` method)."""

    # eq 4-6 (ours, off in `d2slam`, on in `d2slam-flow`): sub-pixel correspondences by pyramidal
    # Lucas-Kanade flow (flow.py). Each current keypoint is tracked into the previous image (matched ones starting at
    # their match), kept when the backward track returns within flow_fb_px; eq 5 then measures the tracked position,
    # and unmatched keypoints that track are observed too. Their alpha and eq 6's sigma are not scaled by the octave
    # (the flow's error does not depend on the detection scale). See flow.py; measured: docs/deviations.md.
    enabled: bool = flag(False)
    flow_window: int = within(11, 3, 101)
    flow_levels: int = within(3, 0, 10)
    flow_iterations: int = within(10, 1, 1000)
    flow_epsilon: float = within(0.03, 0.0, 10.0, lo_open=True)
    flow_fb_px: float = within(0.5, 0.0, 100.0)
    # Where the flow is used: "all"; "matched" (in a mask area, eq 7's inside or uncertain, only matched keypoints
    # are refined, unmatched ones stay unobserved); "outside" (no flow in a mask area: the masks and the ORB matches
    # decide there, as in the paper: people who sit still are geometrically static, and the flow would observe them;
    # measured: docs/deviations.md).
    flow_area: str = one_of("outside", "all", "matched", "outside")
    # The flow's new matches (unmatched keypoints that tracked) get the previous depth image's robust depth at their
    # tracked position, so the RGB-D pose test runs on them too (flow.flow_matches); off: no depth, eq 5 alone.
    # An object carried along its epipolar lines then does not pass eq 5 as static (measured: docs/deviations.md).
    flow_new_depth: bool = flag(True)
    # eq 7 (ours, with the flow only: on in `d2slam-flow`, off in `d2slam`): a keypoint that nothing
    # observed (not matched, the flow did not track it) and that lies outside every mask but within flow_edge_band px
    # of one (eq 1's signed distance d in (-band, 0)) gets P = max(P, flow_edge_p) (fusion.edge_band). Eq 7 gives it
    # P = P_S < 0.5, so it stayed static. These are person pixels the masks missed (boundary errors of the simulated
    # and real masks) or background at a person's silhouette, where a moving edge breaks the descriptor, so few of
    # them are matched and they spend the feature budget without helping tracking. 0 turns it off. Measured:
    # docs/deviations.md.
    flow_edge_band: float = within(6.0, 0.0, 1000.0)
    flow_edge_p: float = within(0.9, 0.0, 1.0)


@dataclass(frozen=True)
class DynamicsConfig(Checked):
    """The paper's constants, each with its equation number (our reading of each: docs/design.md), and our
    deviations in their own sections: ``ours`` (inside the paper's modules), ``pose_test`` and ``flow``."""

    _RULES = (below("z_near", "z_far"), below("beta_min", "beta_max", strict=False),
              below("alpha_min", "alpha_max", strict=False), below("delta_min", "delta_max", strict=False),
              below("gamma_min", "gamma_max", strict=False))
    # Normalised depth s(z) = clip((z - z_near) / (z_far - z_near), 0, 1): the Kinect range.
    z_near: float = within(0.5, 0.0, 20.0)
    z_far: float = within(4.5, 0.0, 20.0, lo_open=True)
    # eq 2: beta(z) = beta_min + (beta_max - beta_min) s(z), proportional to depth.
    beta_min: float = within(0.05, 0.0, 100.0, lo_open=True)
    beta_max: float = within(0.25, 0.0, 100.0, lo_open=True)
    # eq 2 / fig 2: uncertainty zone where neither state reaches this probability (|d| < ln(p/(1-p)) / beta).
    uncertainty_prob: float = within(0.75, 0.5, 1.0, lo_open=True, hi_open=True)
    # eq 5: alpha(z) = alpha_max - (alpha_max - alpha_min) s(z) pixels, inversely proportional to depth.
    alpha_min: float = within(0.5, 0.0, 100.0, lo_open=True)
    alpha_max: float = within(0.9, 0.0, 100.0, lo_open=True)
    # eq 6: sigma of the epipolar-error model, P_g = 1 - exp(-de^2 / (2 sigma^2)) (our reading).
    sigma: float = within(1.0, 0.0, 100.0, lo_open=True)
    # eq 7: weight of the geometric term, in the mask's uncertainty zone / in the reliable area.
    omega_uncertain: float = within(0.5, 0.0, 1.0)
    omega_reliable: float = within(0.1, 0.0, 1.0)
    # eq 7: probability when a keypoint has no observation (not matched, outside every mask area).
    p_no_observation: float = within(0.5, 0.0, 1.0)
    # eq 8: symmetric state-transition probability of the Bayesian filter and prior of new keypoints.
    transition: float = within(0.1, 0.0, 1.0)
    prior: float = within(0.5, 0.0, 1.0)
    dynamic_threshold: float = within(0.5, 0.0, 1.0)
    # eq 9: delta(z) = delta_a - delta_b z pixels, clipped to [delta_min, delta_max]; rho metres.
    delta_a: float = within(48.0, 0.0, 1000.0)
    delta_b: float = within(4.0, 0.0, 1000.0)
    delta_min: float = within(11.0, 0.0, 1000.0)
    delta_max: float = within(48.0, 0.0, 1000.0)
    rho: float = within(0.7, 0.0, 20.0)
    # eq 9 (our reading): interaction zone = within zone_factor * delta(z_n) px of mask n, |z - z_n| < zone_depth.
    zone_factor: float = within(2.0, 0.0, 100.0)
    zone_depth: float = within(1.0, 0.0, 20.0)
    # eq 10: gamma(z) = gamma_max - (gamma_max - gamma_min) s(z) pixels.
    gamma_min: float = within(10.0, 0.0, 1000.0)
    gamma_max: float = within(28.0, 0.0, 1000.0)
    # eq 4-5: fundamental matrix by RANSAC (OpenCV), seeded with the run's seed (FilterInput.seed) for determinism.
    f_ransac_threshold_px: float = within(1.0, 0.0, 100.0, lo_open=True)
    f_ransac_confidence: float = within(0.999, 0.0, 1.0, lo_open=True, hi_open=True)
    f_ransac_max_iters: int = within(500, 1, 1_000_000)
    f_min_matches: int = within(8, 8, 100_000)
    f_min_static_matches: int = within(30, 0, 100_000)
    # "ransac" (cv2.FM_RANSAC), "magsac" (cv2.USAC_MAGSAC) or "usac_accurate".
    f_ransac_method: str = one_of("ransac", "ransac", "magsac", "usac_accurate")
    # `geometric` ablation: fixed epipolar threshold (pixels) instead of alpha(z).
    fixed_alpha: float = within(0.7, 0.0, 100.0, lo_open=True)
    ours: OursConfig = section(OursConfig)
    pose_test: PoseTestConfig = section(PoseTestConfig)
    flow: FlowConfig = section(FlowConfig)


# The fields only the Object Interaction Module reads (eq 9-10 and ours around it), and those only the flow
# correspondences read (ours): a classifier without the OIM, or without flow, reads none of them. A method declares
# what it reads with them (d2slam.run.methods.Method.reads), and the study keys its runs by what they read, so that a
# change to an OIM constant re-runs only the methods with the OIM (tests/test_study_keys.py checks that a change to
# a field a method is said not to read leaves its trajectory byte-identical).
OIM_FIELDS = ("delta_a", "delta_b", "delta_min", "delta_max", "rho", "zone_factor", "zone_depth", "gamma_min",
              "gamma_max", "ours.zone_median_stride", "ours.oim_belief", "ours.oim_skip_observed_static",
              "ours.oim_skip_neighbour_static", "ours.oim_moving_test", "ours.oim_moving_alpha",
              "ours.oim_moving_min")
FLOW_FIELDS = tuple(f"flow.{f.name}" for f in dataclasses.fields(FlowConfig) if f.name != "enabled")


def fields_read(cfg: DynamicsConfig, oim: bool = True, flow: bool = False) -> dict:
    """{dotted name: value} of the ``DynamicsConfig`` fields a classifier reads: every field, but the OIM's without
    the OIM, the flow's without flow (on by the method's switch or by ``flow.enabled``) and the silhouette band's
    likelihood without the band."""
    skip = set() if oim else set(OIM_FIELDS)
    if not (flow or cfg.flow.enabled):
        skip |= set(FLOW_FIELDS)
    if cfg.ours.silhouette_px <= 0:
        skip.add("ours.silhouette_p")
    return {k: v for k, v in flat_fields(cfg).items() if k not in skip}
