"""The engine's settings (docs/design.md#the-engine-and-its-one-hook; ORB-SLAM3 RGB-D settings): ``OrbConfig``
(extraction), ``EngineConfig`` (tracking, local mapping, loop closing)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from d2slam.data.config import ORB_FEATURES_WHY
from d2slam.ranges import INT_MAX, Checked, below, flag, one_of, rule, section, text, within


@dataclass(frozen=True)
class OrbConfig(Checked):
    # The pyramid's top level: OpenCV fails once a level's image rounds to 0 pixels (a 640x480 frame at scale 4 with 8
    # levels); ORB-SLAM's 1.2^7 = 3.6.
    _RULES = (below("fast_min_threshold", "fast_threshold", strict=False),
              rule(("scale_factor", "n_levels"), lambda s, n: s ** (n - 1) <= 32.0,
                   "{0} and {1}: scale_factor^(n_levels - 1) must not exceed 32 (the top level of the image pyramid "
                   "would keep too few pixels)"))
    n_features: int = within(1000, 1, 100_000, why=ORB_FEATURES_WHY)
    scale_factor: float = within(1.2, 1.0, 2.0, lo_open=True)
    n_levels: int = within(8, 1, 20)
    fast_threshold: int = within(20, 0, 255)
    fast_min_threshold: int = within(7, 0, 255)
    edge_threshold: int = within(19, 0, 100)
    patch_size: int = within(31, 2, 100, why="OpenCV's ORB asserts patchSize >= 2")
    # Spatial bucketing: the image is cut in cells of about this size (pixels) at level 0 (x scale^level above).
    cell_size: int = within(35, 4, 1000)
    # Corners detected per kept feature before bucketing (OpenCV ORB keeps the best by Harris response).
    oversample: float = within(2.0, 1.0, 10.0)
    # Keypoint depth: median of the valid depth pixels in a (2 r + 1)^2 patch around the keypoint.
    depth_patch_radius: int = within(1, 0, 20)


@dataclass(frozen=True)
class TrackingConfig(Checked):
    """Tracking (ORB-SLAM3 Tracking): motion-only BA, the searches by projection (last frame, reference keyframe,
    local map) and their thresholds, initialisation."""

    # Motion-only BA weighs u_R as ORB-SLAM3 does (1 px x scale) in its first pose_opt_coarse_rounds rounds and with
    # disparity_sigma_px after them; 4 = all rounds (ORB-SLAM3 PoseOptimization): the disparity model serves local BA
    # only. With 1, real Kinect frames whose depth image was taken ~15 ms before or after the colour image while the
    # camera turned lost their correct matches as outliers (fr1/rpy), and `none` held on the synthetic walking
    # sequences because people's depths disagree with the map. Measured: docs/real_data.md.
    pose_opt_coarse_rounds: int = within(4, 0, 100)
    # Motion-only BA: rounds of optimisation with outlier classification, iterations per round.
    pose_opt_rounds: int = within(4, 1, 100)
    pose_opt_iterations: int = within(10, 1, 1000)
    # g2o terminate action: stop a round when chi2 improves less than this
    pose_opt_gain_threshold: float = within(1e-4, 0.0, 1000.0)
    # Matching (ORB-SLAM ORBmatcher): Hamming thresholds, nearest-neighbour ratios, search radii (pixels x scale).
    # motion-model search: below this, search again with twice the radius
    tracking_min_matches: int = within(20, 0, 100_000)
    tracking_min_inliers: int = within(10, 0, 100_000)  # after motion-only BA (motion model / reference keyframe)
    reference_min_matches: int = within(15, 0, 100_000)
    local_map_min_inliers: int = within(30, 0, 100_000)
    nn_ratio_local_map: float = within(0.8, 0.0, 1.0, lo_open=True)
    nn_ratio_reference: float = within(0.7, 0.0, 1.0, lo_open=True)
    # ORB-SLAM3 RGB-D (non-stereo sensor): th = 15
    search_radius_last_frame: float = within(15.0, 0.0, 1000.0, lo_open=True)
    search_radius_local_map: float = within(3.0, 0.0, 1000.0, lo_open=True)  # ORB-SLAM3 RGB-D: th = 3
    # Local-map search radius factor by viewing angle (ORB-SLAM RadiusByViewingCos): frontal (cos above this) or not.
    local_map_frontal_cos: float = within(0.998, -1.0, 1.0)
    local_map_radius_frontal: float = within(2.5, 0.0, 1000.0, lo_open=True)
    local_map_radius_oblique: float = within(4.0, 0.0, 1000.0, lo_open=True)
    # ORB-SLAM isInFrustum: the point's distance within [0.8 dmin, 1.2 dmax], viewing angle within 60 deg.
    frustum_dmin_factor: float = within(0.8, 0.0, 1.0, lo_open=True)
    frustum_dmax_factor: float = within(1.2, 1.0, 100.0)
    frustum_view_cos: float = within(0.5, -1.0, 1.0)
    # Initialisation (ORB-SLAM StereoInitialization): keypoints with valid depth needed for the first keyframe.
    init_min_keypoints: int = within(500, 1, 100_000)
    # Tracking the local map: keyframes sharing points with the frame (at most this many) + their covisibles.
    local_map_max_keyframes: int = within(80, 1, 100_000)
    local_map_neighbours: int = within(10, 0, 1000)
    local_map_neighbour_sources: int = within(3, 0, 1000)  # ... covisibles of the best this many keyframes


@dataclass(frozen=True)
class RelocalisationConfig(Checked):
    """Relocalisation (ORB-SLAM3 Relocalization): candidate keyframes, descriptor matching, PnP RANSAC, the local-map
    search after it."""

    _RULES = (below("relocalisation_pnp_candidates", "relocalisation_candidates", strict=False),)
    relocalisation_min_inliers: int = within(50, 0, 100_000)
    nn_ratio_relocalisation: float = within(0.75, 0.0, 1.0, lo_open=True)
    search_radius_relocalisation: float = within(10.0, 0.0, 1000.0, lo_open=True)
    # Local-map search radius on the relocalised frame (ORB-SLAM3 SearchLocalPoints: 15 while the state is still
    # RECENTLY_LOST) and on the frame after it (5).
    search_radius_relocalised: float = within(15.0, 0.0, 1000.0, lo_open=True)
    search_radius_after_relocalisation: float = within(5.0, 0.0, 1000.0, lo_open=True)
    # Relocalisation (no DBoW2): descriptor matching against the most recent keyframes, then PnP RANSAC.
    relocalisation_candidates: int = within(10, 1, 1000)
    # ... of which the best by descriptor votes get the PnP attempt (Engine._relocalisation_shortlist).
    relocalisation_pnp_candidates: int = within(3, 1, 1000)
    # PnP RANSAC of a candidate's matches (ORB-SLAM3's PnPsolver: 300 iterations; the pose test's own PnP is
    # dynamics.pose_test's).
    relocalisation_pnp_iterations: int = within(300, 1, 1_000_000)
    relocalisation_pnp_px: float = within(4.0, 0.0, 1000.0, lo_open=True)
    relocalisation_pnp_confidence: float = within(0.99, 0.0, 1.0, lo_open=True, hi_open=True)


@dataclass(frozen=True)
class KeyframeConfig(Checked):
    """The keyframe decision and creation (ORB-SLAM3 NeedNewKeyFrame, CreateNewKeyFrame)."""

    _RULES = (below("kf_min_frames", "kf_max_frames", strict=False),)
    # Keyframe decision (ORB-SLAM3 RGB-D NeedNewKeyFrame): tracked-point ratio, close points, max/min frames.
    kf_tracked_ratio: float = within(0.75, 0.0, 1.0)  # thRefRatio for RGB-D (0.4 while the map has a single keyframe)
    kf_tracked_ratio_first: float = within(0.4, 0.0, 1.0)
    kf_min_frames: int = within(0, 0, 1_000_000)
    kf_max_frames: int = within(30, 0, 1_000_000)
    # Local mapping counts as busy for this many frames after a keyframe (ours: emulates ORB-SLAM3's asynchronous
    # local mapping, during which only the "tracking weak" rule inserts keyframes). 0 = always idle.
    kf_mapping_busy_frames: int = within(3, 0, 1_000_000)
    kf_close_tracked: int = within(100, 0, 100_000)
    kf_close_untracked: int = within(70, 0, 100_000)
    kf_min_inliers: int = within(15, 0, 100_000)
    # c1c: tracking weak when the inliers fall below this share of the reference's points
    kf_weak_ratio: float = within(0.25, 0.0, 1.0)
    # The reference keyframe's points counted by the decision: those with at least this many observations (2 while
    # the map has at most two keyframes).
    kf_ref_min_obs: int = within(3, 1, 1000)
    kf_ref_min_obs_first: int = within(2, 1, 1000)
    # CreateNewKeyFrame: close points added until at least this many (maxPoint)
    kf_new_points_min: int = within(100, 0, 100_000)
    # ... and all closer than this (m) as well (ours): ORB-SLAM3 gets its far points by triangulating keypoints between
    # keyframes (CreateNewMapPoints), which our engine does not do; its keyframes make points from depth up to the
    # Kinect range instead (DynamicsConfig.z_far; 0 = ORB-SLAM3's rule, th_depth * b = 3 m): with people filling the
    # near field, ORB-SLAM3's rule leaves keyframes few static points. The keyframe decision keeps th_depth. Measured:
    # docs/deviations.md.
    kf_new_points_depth: float = within(4.5, 0.0, 100.0)


@dataclass(frozen=True)
class MappingConfig(Checked):
    """Local mapping (ORB-SLAM3 LocalMapping): map-point culling, the neighbours' search, local BA, keyframe culling."""

    # Local mapping.
    local_ba_iterations: int = within(10, 0, 1000)
    # True (ours): after local BA, an observation above the chi-square thresholds whose image residual alone passes
    # the monocular test keeps its image observation, and its keyframe's depth at the keypoint is dropped (u_R = -1);
    # False: the whole observation is erased (ORB-SLAM3, whose 1 px x scale u_R rarely fails where the image passes).
    # With disparity_sigma_px a Kinect depth taken ~15 ms away from the colour image while the camera turns fails, and
    # erasing cost a real keyframe its observations (fr1/rpy: the reference keyframe left with 4 points seen twice, no
    # keyframe for 43 frames). Measured: docs/real_data.md.
    lba_depth_outliers_mono: bool = flag(True)
    # True: a keyframe's local BA and keyframe culling run at the next frame that makes no keyframe, and are skipped
    # when that frame makes one (ORB-SLAM3's local mapping runs beside tracking and skips them while another keyframe
    # waits in its queue, aborting a running BA when one arrives). False: right after the keyframe, every time.
    ba_when_idle: bool = flag(True)
    # SearchInNeighbors (ORB-SLAM3 LocalMapping, with ORBmatcher::Fuse): the new keyframe's points are projected into
    # its best fuse_neighbours covisibles and their best fuse_second_neighbours covisibles (ORB-SLAM3 1.0: 10 and 20),
    # and theirs into it (radius fuse_radius x scale, chi-square test, Hamming <= desc_th_low): a free keypoint gains
    # an observation, a keypoint with a point merges the two points. 0 = off. Without it, a keyframe's points are seen
    # by few others, the keyframe decision's tracked-ratio test rarely holds and keyframes come late (fr1/rpy and its
    # synthetic twin: 26 keyframes against ORB-SLAM3's 78). Measured: docs/real_data.md.
    fuse_neighbours: int = within(10, 0, 1000)
    fuse_second_neighbours: int = within(20, 0, 1000)
    fuse_radius: float = within(3.0, 0.0, 1000.0, lo_open=True)
    # ... its chi-square test weighs u_R at disparity_sigma_px (True, as local BA) or at 1 px x scale (False, ORB-SLAM3)
    fuse_disparity_model: bool = flag(False)
    # CreateNewMapPoints (ORB-SLAM3 LocalMapping, with ORBmatcher::SearchForTriangulation): the new keyframe's
    # keypoints without a point are matched with the free keypoints of its best triangulate_neighbours covisibles
    # (ORB-SLAM3 RGB-D: 10; same vocabulary node, Hamming <= desc_th_low, within triangulation_epipolar_chi2 x sigma^2
    # of the epipolar line, away from the epipole, orientation check) and each match becomes a point, triangulated
    # (rays' cos below triangulation_max_cos_parallax without depth) or from a keyframe's depth, in front of both
    # keyframes, within the chi-square tests in both, its distances to them consistent with the octaves within
    # triangulation_ratio_factor x OrbConfig.scale_factor. 0 = off.
    triangulate_neighbours: int = within(0, 0, 1000)
    triangulation_max_cos_parallax: float = within(0.9998, -1.0, 1.0)
    triangulation_epipolar_chi2: float = within(3.84, 0.0, 1000.0, lo_open=True, why="chi-square, 1 dof (95 %: 3.84)")
    triangulation_epipole_px: float = within(10.0, 0.0, 1000.0)  # ... px x sqrt(scale) from the epipole (ORB-SLAM3)
    triangulation_ratio_factor: float = within(1.5, 1.0, 100.0)
    # ORB-SLAM3 MapPoint::ComputeDistinctiveDescriptors and UpdateNormalAndDepth whenever local mapping adds
    # observations (ProcessNewKeyFrame, CreateNewMapPoints, SearchInNeighbors): a point's descriptor becomes the medoid
    # of its observations', its normal the mean viewing ray, its distance range from its reference keyframe. False: the
    # descriptor, normal and range it was made with.
    update_points: bool = flag(False)
    local_ba_window: int = within(10, 1, 1000)  # covisible keyframes optimised with the new one (best by shared points)
    # keyframes held fixed (best by observations of the local points; ours, for speed)
    local_ba_max_fixed: int = within(5, 0, 1000)
    mappoint_found_ratio: float = within(0.25, 0.0, 1.0)
    mappoint_min_obs: int = within(3, 0, 1000)  # ORB-SLAM cnThObs (RGB-D): weighted observations (stereo counts 2)
    mappoint_cull_age: int = within(2, 0, 1000)  # ... checked once a point is this many keyframes old
    # points stay on the recent list (MapPointCulling) for this many keyframes
    mappoint_recent_age: int = within(3, 0, 1000)
    # KeyFrameCulling (ORB-SLAM3): a keyframe is redundant when more than keyframe_redundancy of its close points are
    # seen by more than keyframe_redundant_obs other keyframes (ORB-SLAM3 1.0 counts nObs > 3; its comment and
    # ORB-SLAM2, >= 3) at the same or a finer scale.
    keyframe_redundancy: float = within(0.9, 0.0, 1.0)
    keyframe_redundant_obs: int = within(3, 1, 1000)


@dataclass(frozen=True)
class LoopConfig(Checked):
    """Loop closing and place recognition (ORB-SLAM3 LoopClosing, KeyFrameDatabase): detection, geometry, correction."""

    bow_levelsup: int = within(4, 0, 10)  # ORB-SLAM3: feature-vector nodes 4 levels above the words
    # True (an ablation: dynamics-unaware place recognition): the keypoints the hook flags dynamic enter the bags of
    # words and the loop's 3D-3D matches all the same (tracking and mapping still leave them out).
    loop_dynamic_keypoints: bool = flag(False)
    # Detection (ORB-SLAM2/3 DetectLoop): not before the map has loop_min_keyframes keyframes nor within loop_gap
    # keyframes of the last loop; candidates score at least the lowest score of the keyframe's covisible keyframes
    # (those sharing >= covisibility_min_shared points, which are never candidates), share more than
    # loop_common_words of the best candidate's common words, and their group (with their loop_group_size best
    # covisibles) accumulates more than loop_group_ratio of the best group's score; a candidate group must recur over
    # loop_consistency consecutive keyframes (ORB-SLAM's covisibility consistency).
    loop_min_keyframes: int = within(10, 0, 100_000)
    loop_gap: int = within(10, 0, 100_000)
    loop_common_words: float = within(0.8, 0.0, 1.0)
    loop_group_size: int = within(10, 0, 1000)
    loop_group_ratio: float = within(0.75, 0.0, 1.0)
    loop_consistency: int = within(3, 0, 1000)
    # Geometry (ORB-SLAM3 Sim3 with the scale fixed for RGB-D): the keyframe's static keypoints with depth matched
    # (2-NN, ratio loop_nn_ratio, Hamming <= desc_th_low) to the points of the candidate and its loop_window best
    # covisibles; 3-point RANSAC of the rigid transform (loop_ransac_iterations, seeded), inliers by the reprojection
    # chi-square (loop_ransac_chi2 x sigma^2, ORB-SLAM's 9.21, in the image and in u_R); at least loop_min_inliers;
    # then the window's points projected with that pose (radius loop_search_radius x scale) and the pose optimised
    # (motion-only BA): at least loop_min_matches inliers accept the loop.
    loop_nn_ratio: float = within(0.75, 0.0, 1.0, lo_open=True)
    loop_window: int = within(10, 0, 1000)
    loop_ransac_iterations: int = within(300, 1, 1_000_000)
    loop_ransac_chi2: float = within(9.21, 0.0, 1000.0, lo_open=True)
    loop_min_inliers: int = within(20, 3, 100_000, why='3-point RANSAC')
    loop_search_radius: float = within(10.0, 0.0, 1000.0, lo_open=True)
    loop_min_matches: int = within(40, 0, 100_000)
    # Correction (ORB-SLAM3 CorrectLoop): the keyframe's covisibles moved with it, the loop window's points fused
    # into them (radius loop_fuse_radius x scale), pose-graph optimisation of the essential graph (spanning tree,
    # covisibility edges of at least essential_min_shared points, loop edges; loop_pgo_iterations of
    # Levenberg-Marquardt, the loop keyframe fixed), then a full BA (loop_full_ba_iterations; the first keyframe
    # fixed).
    loop_fuse_radius: float = within(4.0, 0.0, 1000.0, lo_open=True)
    essential_min_shared: int = within(100, 0, 100_000)
    loop_pgo_iterations: int = within(20, 0, 1000)
    loop_full_ba_iterations: int = within(10, 0, 1000)


@dataclass(frozen=True)
class EngineConfig(Checked):
    """The engine (ORB-SLAM3 RGB-D): the settings every stage shares, its parts' own sections, and which parts it
    has (loop closing)."""

    _RULES = (below("min_depth", "max_depth"), below("desc_th_low", "desc_th_high", strict=False))
    # Virtual stereo: u_R = u - bf / z; points closer than th_depth * b (b = bf / fx) are "close".
    th_depth: float = within(40.0, 0.0, 1000.0, lo_open=True)
    # True: every keypoint with valid depth gets u_R and a stereo edge (ORB-SLAM2/3 ComputeStereoFromRGBD); th_depth
    # then only decides which points are "close" (new map points, keyframe decision, keyframe culling). False: far
    # points (beyond th_depth * b) get monocular edges.
    stereo_far_points: bool = flag(True)
    # Ours: with a keypoint filter, each frame extracts OrbConfig.n_features plus as many keypoints as the filter
    # flagged in the previous frame (at most refill_max x n_features), so tracking and mapping keep about n_features
    # usable keypoints, as DynaSLAM's extraction outside the masks does. Without a filter (none, the static twins)
    # nothing changes. Such runs extract every frame themselves (stored features have the fixed budget). Measured:
    # docs/deviations.md.
    refill_filtered: bool = flag(True)
    refill_max: float = within(1.5, 1.0, 10.0)
    min_depth: float = within(0.1, 0.0, 100.0)
    max_depth: float = within(8.0, 0.0, 100.0, lo_open=True)
    # Stereo observations (u, v, u_R): 0 = ORB-SLAM's information I / sigma_level^2 (u_R as noisy as a stereo match).
    # > 0 (ours, RGB-D): u_R = u - bf / z carries u's error plus the depth's disparity error of this many pixels
    # (optimizer.stereo_information). A Kinect's depth noise grows as sigma_z = k z^2 (k = 1.425e-3 / m, Khoshelham
    # & Elberink 2012), i.e. a constant disparity error bf * k = 0.057 px at bf = 40 (the synthetic sensor's: 0.06-0.08
    # px over 1-3 m); ORB-SLAM's 1 px x scale lets points slide in depth and local BA drag keyframes with them.
    # Measured: docs/deviations.md.
    disparity_sigma_px: float = within(0.057, 0.0, 100.0)
    # Chi-square thresholds at 95 % (ORB-SLAM): 2 dof mono, 3 dof stereo.
    chi2_mono: float = within(5.991, 0.0, 1000.0, lo_open=True)
    chi2_stereo: float = within(7.815, 0.0, 1000.0, lo_open=True)
    desc_th_high: int = within(100, 0, 256, why='Hamming distance of 256-bit descriptors')
    desc_th_low: int = within(50, 0, 256, why='Hamming distance of 256-bit descriptors')
    rotation_histogram_bins: int = within(30, 1, 360)  # ORB-SLAM HISTO_LENGTH: orientation-consistency histogram
    # keypoint grid cell (px) of searches by projection (ORB-SLAM: 64 x 48 cells)
    search_grid_cell: float = within(10.0, 0.0, 1000.0, lo_open=True)
    check_orientation: bool = flag(True)
    # Both optimisations: "lm" (compiled Levenberg-Marquardt, d2slam.slam.lm) or "g2o" (the g2opy wheel, same
    # model; its graph is built edge by edge from Python, several times slower).
    optimizer: Literal["lm", "g2o"] = one_of("lm", "lm", "g2o")
    covisibility_min_shared: int = within(15, 1, 100_000)
    # Keypoint filter (hook): frame-to-frame mutual-nearest matches within this pixel displacement.
    filter_match_window: float = within(80.0, 0.0, 10_000.0, lo_open=True)
    # ... guided instead when the frame's pose is predicted (Engine.filter_matches): previous keypoints moved by the
    # constant-velocity model and searched within this radius (px x scale) on their level +-1, ratio test; fewer
    # than filter_guided_min_matches guided matches -> the window matching above.
    filter_match_guided: bool = flag(True)
    filter_match_radius: float = within(15.0, 0.0, 1000.0, lo_open=True)
    filter_match_nn_ratio: float = within(0.9, 0.0, 1.0, lo_open=True)
    filter_guided_min_matches: int = within(50, 0, 100_000)
    # Map points with a dynamic belief above this are culled (hook output, eq 8).
    mappoint_belief_threshold: float = within(0.5, 0.0, 1.0)
    # The run's seed (`d2slam run --seed`, the study's seed): every random draw of a run comes from a stream derived
    # from it: relocalisation's PnP RANSAC (seed + the frame's index), loop closing's RANSAC ([seed, the keyframe's
    # frame index]), the keypoint filter's RANSAC (F and the pose test's PnP: seed, FilterInput.seed) and the
    # depth-scale check of `d2slam run` (seed).
    seed: int = within(0, 0, INT_MAX, why="a seed")
    # OpenCV thread count, set explicitly (cv2.setNumThreads) for deterministic, reproducible timings.
    cv_threads: int = within(1, 0, 1024)
    # Loop closing (ORB-SLAM3 LoopClosing for RGB-D, run synchronously after local mapping) and place recognition
    # (a DBoW2 keyframe database, which relocalisation also uses). False: the engine without either (relocalisation
    # by descriptor votes over the recent keyframes, relocalisation_candidates).
    loop_closing: bool = flag(True)
    # DBoW2 text vocabulary ("" = the real ORB-SLAM3's: $PYORBSLAM3_VOCAB, else the project's `d2slam vocab build`,
    # built on first use); a keypoint the hook flags dynamic enters no bag of words (loop_dynamic_keypoints).
    vocabulary: str = text("", "a DBoW2 text vocabulary file, or \"\" for the project's")
    tracking: TrackingConfig = section(TrackingConfig)
    relocalisation: RelocalisationConfig = section(RelocalisationConfig)
    keyframes: KeyframeConfig = section(KeyframeConfig)
    mapping: MappingConfig = section(MappingConfig)
    loops: LoopConfig = section(LoopConfig)


@dataclass(frozen=True)
class SlamConfig(Checked):
    """What the engine reads of a whole config (``d2slam.config.Config`` has these sections too, under the same
    names, and passes for one)."""

    # The engine initialises on a frame with init_min_keypoints keypoints with depth: fewer features never track.
    _RULES = (rule(("orb.n_features", "engine.tracking.init_min_keypoints"), lambda n, k: n >= k,
                   "{0} must be at least {1}: the engine could never initialise"),)

    orb: OrbConfig = section(OrbConfig)
    engine: EngineConfig = section(EngineConfig)
