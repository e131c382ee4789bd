"""Loop closing and place recognition on small generated inputs: the vocabulary loader, bags of words and the
inverted file, ORB-SLAM's candidate rules and consistency, dynamics-aware words, the 3D-3D RANSAC, the pose graph,
loops judged against the ground truth, the switch, and a loop closed by the engine in an analytic room."""

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from d2slam.baselines.vocab import Vocabulary, build_tree
from d2slam.config import DEFAULT, EvalConfig
from d2slam.data.base import Camera, Trajectory
from d2slam.eval.loops import classify_loops, closest_call, wrong_candidates
from d2slam.ranges import overridden
from d2slam.slam import lm
from d2slam.slam.engine import Engine
from d2slam.slam.fixture import BoxRoom
from d2slam.slam.keyframe_database import KeyFrameDatabase
from d2slam.slam.local_mapping import LocalMapper
from d2slam.slam.loop_closing import Candidate, LoopCloser, kabsch
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.optimizer import pose_graph_optimization, se3_log
from d2slam.slam.orb_vocabulary import _load, load_vocabulary, score
from d2slam.slam.projection import Projector, inv

CAM = Camera(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240, bf=20.0)


def _cfg(**engine):
    """DEFAULT with these engine fields (nested sections as dicts: ``loops={"loop_consistency": 2}``)."""
    return overridden(DEFAULT, {"engine": engine})


@pytest.fixture(scope="module")
def vocab_file(tmp_path_factory):
    """A small DBoW2 vocabulary (k=8, L=3) trained on random descriptors."""
    rng = np.random.default_rng(0)
    desc = rng.integers(0, 256, (6000, 32), dtype=np.uint8)
    path = tmp_path_factory.mktemp("voc") / "voc.txt"
    build_tree(desc, np.arange(6000) // 200, k=8, L=3, seed=0).save(path)
    return path


@pytest.fixture()
def voc(vocab_file, tmp_path, monkeypatch):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    return load_vocabulary(str(vocab_file))


def _kf(id_, desc, n=None, dynamic=None, Tcw=None):
    n = len(desc) if n is None else n
    z = np.full(n, 2.0)
    return KeyFrame(id=id_, frame_index=10 * id_, timestamp=float(id_), Tcw=np.eye(4) if Tcw is None else Tcw,
                    kps=np.zeros((n, 2)), octave=np.zeros(n, np.int64), angle=np.zeros(n, np.float32), desc=desc,
                    depth=z, ur=z.copy(), inv_sigma2=np.ones(n), mp=np.full(n, -1, np.int64), dynamic=dynamic)


# ------------------------------------------------------------------ vocabulary and bags of words
def test_vocabulary_loader_matches_the_text_reader_and_caches(vocab_file, tmp_path, monkeypatch):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    _load.cache_clear()
    voc = load_vocabulary(str(vocab_file))
    ref = Vocabulary.load(vocab_file)
    d = np.random.default_rng(1).integers(0, 256, (200, 32), dtype=np.uint8)
    words, nodes = voc.transform(d, levelsup=2)
    np.testing.assert_array_equal(words, ref.transform(d))
    depth = ref.depth()
    assert (depth[nodes] == 1).all()  # L - levelsup = 1: the ancestor one level below the root
    assert ((ref.parent[words] == nodes) | (ref.parent[ref.parent[words]] == nodes)).all()
    assert load_vocabulary(str(vocab_file)) is voc  # once per process
    npz = list((tmp_path / "cache" / "vocab" / "bow").glob("*.npz"))
    assert len(npz) == 1  # the derived file, read next time
    _load.cache_clear()
    again = load_vocabulary(str(vocab_file))
    np.testing.assert_array_equal(again.children, voc.children)
    np.testing.assert_array_equal(again.weight, voc.weight)


def test_bow_is_l1_normalised_tf_idf_and_scores_as_dbow2(voc):
    rng = np.random.default_rng(2)
    a, b = rng.integers(0, 256, (300, 32), dtype=np.uint8), rng.integers(0, 256, (300, 32), dtype=np.uint8)
    ia, wa, words, _ = voc.bow(a, 2)
    assert np.isclose(wa.sum(), 1.0) and (np.diff(ia) > 0).all()
    raw = np.bincount(words, weights=voc.weight[words], minlength=voc.n_nodes)
    np.testing.assert_allclose(wa, raw[ia] / raw.sum())
    ib, wb, _, _ = voc.bow(b, 2)
    va, vb = np.zeros(voc.n_nodes), np.zeros(voc.n_nodes)
    va[ia], vb[ib] = wa, wb
    assert np.isclose(score(ia, wa, ib, wb), 1 - 0.5 * np.abs(va - vb).sum())  # DBoW2's L1 score
    assert np.isclose(score(ia, wa, ia, wa), 1.0)


def test_inverted_file_counts_common_words_and_scores_all_keyframes(voc):
    rng = np.random.default_rng(3)
    m = Map()
    db = KeyFrameDatabase(voc, m, DEFAULT.engine)
    descs = [rng.integers(0, 256, (150, 32), dtype=np.uint8) for _ in range(5)]
    for i, d in enumerate(descs):
        m.add_keyframe(_kf(i, d))
        db.add(m.keyframes[i])
    q = db.bow(descs[2], None)
    kfs, common = db._sharing(q, np.zeros(0, np.int64))
    for k, c in zip(kfs, common):
        assert c == len(np.intersect1d(q.words, db.bows[int(k)].words))
    sc = db.scores(q, np.arange(5))
    ref = [score(q.words, q.weights, db.bows[k].words, db.bows[k].weights) for k in range(5)]
    np.testing.assert_allclose(sc, ref)
    assert np.argmax(sc) == 2 and np.isclose(sc[2], 1.0)
    m.keyframes[2].bad = True  # culled keyframes are never candidates
    assert 2 not in db._sharing(q, np.zeros(0, np.int64))[0]


def _descriptors_with_dynamic(n: int = 200, n_dynamic: int = 120):
    """n random ORB descriptors, the first n_dynamic of them flagged dynamic."""
    d = np.random.default_rng(4).integers(0, 256, (n, 32), dtype=np.uint8)
    return d, np.arange(n) < n_dynamic


def test_dynamic_keypoints_give_no_word(voc):
    d, dyn = _descriptors_with_dynamic()
    m = Map()
    db = KeyFrameDatabase(voc, m, DEFAULT.engine)
    m.add_keyframe(_kf(0, d, dynamic=dyn))
    bow = db.add(m.keyframes[0])
    assert (bow.kp_words[dyn] == -1).all() and (bow.kp_nodes[dyn] == -1).all() and (bow.kp_words[~dyn] >= 0).all()
    static = voc.bow(d[~dyn], 2)
    np.testing.assert_array_equal(bow.words, static[0])
    np.testing.assert_allclose(bow.weights, static[1])
    m.add_keyframe(_kf(1, d))  # no filter (none): every keypoint gives its word
    np.testing.assert_array_equal(db.add(m.keyframes[1]).words, voc.bow(d, 2)[0])


# ------------------------------------------------------------------ candidate rules
def _place_map(voc, cfg):
    """Keyframes: 0 (query) and 1 connected to it (30 shared points, few similar words); 2 and 3 the same place as 0
    (similar words), connected to each other; 4 another place (one word)."""
    rng = np.random.default_rng(5)
    base = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    other = rng.integers(0, 256, (1, 32), dtype=np.uint8)

    def near(d, flip):
        d = d.copy()
        d[:flip] = rng.integers(0, 256, (flip, 32), dtype=np.uint8)
        return d

    descs = [base, near(base, 150), near(base, 20), near(base, 40), np.repeat(other, 200, axis=0)]
    m = Map()
    for i, d in enumerate(descs):
        m.add_keyframe(_kf(i, d))
    for a, b in ((0, 1), (2, 3)):
        ids = m.add_points(np.zeros((30, 3)), np.zeros((30, 32), np.uint8), np.zeros((30, 3)), np.zeros(30),
                           np.ones(30), np.zeros(30), a, np.zeros(30, np.float32), np.zeros(30, np.int64))
        free_a = np.flatnonzero(m.keyframes[a].mp < 0)[:30]
        free_b = np.flatnonzero(m.keyframes[b].mp < 0)[:30]
        m.add_observations(m.keyframes[a], free_a, ids)
        m.add_observations(m.keyframes[b], free_b, ids)
    db = KeyFrameDatabase(voc, m, cfg)
    for kf in m.keyframes:
        db.add(kf)
    return m, db


def test_loop_candidates_follow_orbslam_rules(voc):
    cfg = DEFAULT.engine
    m, db = _place_map(voc, cfg)
    assert db.connected(0) == [1] and db.connected(2) == [3] and db.tree_parent(1) == 0
    min_score = float(db.scores(db.bows[0], np.array(db.connected(0))).min())
    cands, passed = db.loop_candidates(0, min_score)
    got = {k for k, _ in passed}
    assert 1 not in got and 0 not in got  # the keyframe and its connected keyframes are never candidates
    assert 4 not in got  # below the minimum score of the covisible keyframes
    assert [c for c, _, _ in cands] == [2]  # 2 and 3 form one group; its best keyframe is the candidate
    acc = dict((c, a) for c, a, _ in cands)[2]
    s2, s3 = db.scores(db.bows[0], np.array([2, 3]))
    assert np.isclose(acc, s2 + s3)  # the group accumulates its keyframes' scores
    assert db.loop_candidates(0, 1.01)[0] == []
    # relocalisation: no exclusion, no minimum score; the group of 2 and 3 outscores keyframe 0 alone (its neighbour
    # 1 shares too few words), by more than 1 / loop_group_ratio
    assert db.relocalisation_candidates(m.keyframes[0].desc, np.ones(200, bool)) == [2]


def test_candidates_must_be_consistent_over_consecutive_keyframes(voc):
    cfg = _cfg(loops={"loop_consistency": 2}).engine
    m, db = _place_map(voc, cfg)
    lc = LoopCloser.__new__(LoopCloser)
    lc.db, lc.cfg, lc.groups = db, cfg, []
    assert lc.consistent([2]) == []  # group {2, 3}: consistency 0
    assert lc.consistent([3]) == []  # shares 3 with it: 1
    assert lc.consistent([2]) == [2]  # 2: enough
    assert lc.consistent([4]) == []  # another place: a new group
    lc.groups = []  # a keyframe without candidates clears the groups (detect)
    assert lc.consistent([2]) == []


# ------------------------------------------------------------------ geometry
def test_kabsch_recovers_a_rigid_transform():
    rng = np.random.default_rng(6)
    R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    t = np.array([0.4, -1.0, 2.0])
    X = rng.normal(size=(2, 10, 3))
    Rh, th = kabsch(X, X @ R.T + t)
    np.testing.assert_allclose(Rh, np.stack([R, R]), atol=1e-12)
    np.testing.assert_allclose(th, np.stack([t, t]), atol=1e-12)


def _pair(n=300, outliers=0.3, seed=7):
    """A candidate keyframe seeing n points and the current keyframe seeing them from another pose, its own map
    drifted (its pose in the candidate's map is unknown); ``bad`` marks a share ``outliers`` of the keypoints."""
    rng = np.random.default_rng(seed)
    proj = Projector(CAM, DEFAULT)
    X = np.c_[rng.uniform(-1.5, 1.5, n), rng.uniform(-1.0, 1.0, n), rng.uniform(2.0, 4.0, n)]
    T_cand = np.eye(4)
    T_cur = np.eye(4)
    T_cur[:3, :3] = Rotation.from_rotvec([0.02, 0.15, -0.03]).as_matrix()
    T_cur[:3, 3] = [0.2, 0.05, 0.1]
    m = Map()
    kfs = []
    for i, T in enumerate((T_cand, T_cur)):
        u, v, z = proj.project(T, X)
        kps = np.c_[u, v] + rng.normal(0, 0.3, (n, 2))
        kf = KeyFrame(id=i, frame_index=100 * i, timestamp=float(i), Tcw=T.copy(), kps=kps,
                      octave=np.zeros(n, np.int64), angle=np.zeros(n, np.float32),
                      desc=rng.integers(0, 256, (n, 32), dtype=np.uint8), depth=z, ur=kps[:, 0] - CAM.bf / z,
                      inv_sigma2=np.ones(n), mp=np.full(n, -1, np.int64))
        m.add_keyframe(kf)
        kfs.append(kf)
    bad = rng.random(n) < outliers  # wrong matches (see the RANSAC test)
    ids = m.add_points(X, kfs[0].desc, np.tile([0, 0, 1.0], (n, 1)), np.full(n, 0.5), np.full(n, 8.0), np.zeros(n),
                       0, np.zeros(n, np.float32), np.zeros(n, np.int64))
    m.add_observations(kfs[0], np.arange(n), ids)
    kfs[1].Tcw = np.eye(4)  # its drifted pose
    return m, proj, kfs, T_cur, bad


def test_ransac_3d3d_recovers_the_pose_in_the_loop_map(voc):
    m, proj, (cand, cur), T_true, bad = _pair()
    lc = LoopCloser(m, proj, DEFAULT, voc, LocalMapper(m, proj, DEFAULT))
    idx = np.arange(len(cur.kps))
    wrong = idx.copy()
    wrong[bad] = np.roll(idx[bad], 1)  # a share of the matches pair a keypoint with another point
    T, inl = lc.ransac(cur, cand, idx, wrong)
    assert np.abs(T - T_true).max() < 0.02  # a 3D fit (refined by the pose optimisation that follows)
    assert inl[~bad].mean() > 0.95 and inl[bad].mean() < 0.05
    T2, _ = lc.ransac(cur, cand, idx, wrong)
    np.testing.assert_array_equal(T, T2)  # seeded


def test_geometry_takes_no_dynamic_keypoint(voc):
    m, proj, (cand, cur), T_true, bad = _pair(outliers=0.0)
    cur.desc = cand.desc.copy()  # the same features: words and descriptors match
    cur.dynamic = np.zeros(len(cur.kps), bool)
    cur.dynamic[::3] = True
    lc = LoopCloser(m, proj, DEFAULT, voc, LocalMapper(m, proj, DEFAULT))
    lc.db.add(cand)
    lc.db.add(cur)
    geo, n = lc.geometry(cur, cand)
    assert geo is not None and n >= DEFAULT.engine.loops.loop_min_matches
    assert not cur.dynamic[geo.kp].any() and len(geo.kp) > 0.6 * (~cur.dynamic).sum()
    assert np.abs(geo.Tcw - T_true).max() < 0.01
    m.points.belief[:] = 1.0  # the loop's points marked dynamic: none is usable
    assert lc.geometry(cur, cand)[0] is None


# ------------------------------------------------------------------ pose graph
def test_se3_log_inverts_exp():
    rng = np.random.default_rng(8)
    xi = rng.normal(0, 0.5, (20, 6))
    xi[0] = 0.0
    T = np.stack([lm.se3_exp(x) for x in xi])
    np.testing.assert_allclose(se3_log(T), xi, atol=1e-9)


def test_pose_graph_spreads_a_planted_drift_over_the_loop():
    n = 24
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    Twc = np.tile(np.eye(4), (n, 1, 1))
    Twc[:, :3, :3] = Rotation.from_rotvec(np.c_[np.zeros(n), ang, np.zeros(n)]).as_matrix()
    Twc[:, 0, 3], Twc[:, 2, 3] = 2 * np.sin(ang), 2 * np.cos(ang)
    truth = np.stack([inv(T) for T in Twc])  # Tcw
    drift = lm.se3_exp(np.array([0.0, 0.01, 0.0, 0.01, 0.0, 0.005]))
    est = [truth[0]]
    for i in range(1, n):  # odometry with a small constant error
        est.append(drift @ truth[i] @ inv(truth[i - 1]) @ est[-1])
    est = np.stack(est)
    ei, ej = np.arange(n - 1), np.arange(1, n)
    meas = np.stack([est[i] @ inv(est[j]) for i, j in zip(ei, ej)])
    loop = truth[n - 1] @ inv(truth[0])  # the loop edge: the true relative pose
    ei, ej, meas = np.r_[ei, n - 1], np.r_[ej, 0], np.concatenate([meas, loop[None]])
    fixed = np.zeros(n, bool)
    fixed[0] = True
    out = pose_graph_optimization(est, fixed, ei, ej, meas, 20)

    def err(P):
        return np.linalg.norm([inv(P[i])[:3, 3] - inv(truth[i])[:3, 3] for i in range(n)], axis=1)

    assert err(est).max() > 0.2
    assert err(out).max() < 0.35 * err(est).max()
    np.testing.assert_array_equal(out[0], est[0])  # fixed
    np.testing.assert_array_equal(out, pose_graph_optimization(est, fixed, ei, ej, meas, 20))


# ------------------------------------------------------------------ loops against the truth
def _gt(n=50):
    Twc = np.tile(np.eye(4), (n, 1, 1))
    Twc[:, 0, 3] = np.linspace(0, 1, n)
    Twc[:, :3, :3] = Rotation.from_rotvec(np.c_[np.zeros(n), np.linspace(0, 2.5, n), np.zeros(n)]).as_matrix()
    return Trajectory(np.arange(n) / 10.0, Twc), np.arange(n) / 10.0


def test_loops_are_true_or_false_by_their_relative_pose():
    gt, ts = _gt()
    T = gt.poses
    good = inv(T[40]) @ T[5]
    off = good.copy()
    off[0, 3] += 0.2  # 20 cm off
    turned = Rotation.from_rotvec([0, np.radians(6), 0]).as_matrix()
    rot = good.copy()
    rot[:3, :3] = turned @ rot[:3, :3]
    loops = [{"frames": [40, 5], "T_kf_loop": good.tolist()}, {"frames": [41, 6], "T_kf_loop": off.tolist()},
             {"frames": [40, 5], "T_kf_loop": rot.tolist()}]
    out = classify_loops(loops, ts, gt)
    assert out["loops"] == [[40, 5], [41, 6], [40, 5]]
    assert out["loops_true"] == [[40, 5]] and out["loops_false"] == [[41, 6], [40, 5]]
    assert out["loop_errors"][0] == pytest.approx([0.0, 0.0], abs=1e-5)
    assert classify_loops(loops, ts, None) == {"loops": out["loops"]}  # no truth: no verdict
    loose = EvalConfig(loop_true_max_m=0.5, loop_true_max_deg=10.0)
    assert len(classify_loops(loops, ts, gt, loose)["loops_true"]) == 3


def test_closest_call_is_the_wrong_candidate_that_went_furthest():
    gt, ts = _gt()
    cands = [Candidate(45, 44, 0.9, 0.1, "geometry", 12),  # same view: not wrong
             Candidate(45, 2, 0.3, 0.1, "score"), Candidate(46, 3, 0.2, 0.1, "geometry", 9),
             Candidate(47, 1, 0.5, 0.1, "group")]
    wrong = wrong_candidates(cands, ts, gt)
    np.testing.assert_array_equal(wrong, [False, True, True, True])
    cc = closest_call(cands, ts, gt)
    assert cc["frames"] == [46, 3] and cc["stage"] == "geometry" and cc["inliers"] == 9 and cc["ratio"] == 2.0
    assert closest_call(cands[:1], ts, gt) is None


# ------------------------------------------------------------------ the engine
def test_switch_off_is_the_engine_without_a_database(vocab_file, monkeypatch, tmp_path):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path))
    off = Engine(CAM, _cfg(loop_closing=False, vocabulary=str(vocab_file)))
    assert off.loop is None and off.tracker.keyframe_db is None and off.vocabulary is None and off.loops == []
    on = Engine(CAM, _cfg(vocabulary=str(vocab_file)))
    assert on.loop is not None and on.tracker.keyframe_db is on.loop.db
    assert DEFAULT.engine.loop_closing  # on by default, as in ORB-SLAM3


@pytest.fixture(scope="module")
def box_loop(tmp_path_factory):
    """84 frames (320 x 240) of an analytic room: the camera turns once round and on by 70 degrees, walking a small
    circle; and a vocabulary trained on every sixth frame."""
    room = BoxRoom(seed=5, texture_px=512)
    n = 84
    th = np.linspace(0, 2 * np.pi + 1.2, n)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(np.c_[np.zeros(n), th, np.zeros(n)]).as_matrix()
    poses[:, 0, 3], poses[:, 2, 3] = 0.3 * np.sin(th), 0.3 * (np.cos(th) - 1)
    frames = [room.render(T, CAM) for T in poses]
    orb = cv2.ORB_create(500)
    descs = [orb.detectAndCompute(g, None)[1] for g, _ in frames[::6]]
    path = tmp_path_factory.mktemp("boxvoc") / "voc.txt"
    build_tree(np.concatenate(descs), np.repeat(np.arange(len(descs)), [len(d) for d in descs]), k=6, L=4,
               seed=0).save(path)
    return frames, poses, path


def _box_run(box_loop, loop_closing):
    frames, poses, path = box_loop
    cfg = overridden(DEFAULT, {"orb": {"n_features": 500},
                               "engine": {"loop_closing": loop_closing, "vocabulary": str(path),
                                          "tracking": {"init_min_keypoints": 200}, "keyframes": {"kf_max_frames": 4},
                                          "loops": {"loop_consistency": 0}}})
    eng = Engine(CAM, cfg)
    for i, (g, d) in enumerate(frames):
        assert eng.process(g, d, i, i / 30.0).tracked
    return eng


def test_engine_closes_the_loop_of_a_room_and_is_deterministic(box_loop, monkeypatch, tmp_path):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path))
    frames, poses, _ = box_loop
    on, off = _box_run(box_loop, True), _box_run(box_loop, False)
    assert len(on.loops) == 1 and off.loops == []
    lp = on.loops[0]
    assert lp.frame > 60 and lp.loop_frame < 10  # after the turn, back to its start
    truth = inv(poses[lp.frame]) @ poses[lp.loop_frame]
    assert np.linalg.norm(lp.T_kf_loop[:3, 3] - truth[:3, 3]) < 0.02

    def end_error(eng):
        idx, _, P = eng.trajectory()
        est = inv(P[0]) @ P[-1]
        return np.linalg.norm(est[:3, 3] - (inv(poses[idx[0]]) @ poses[idx[-1]])[:3, 3])

    assert end_error(on) < 0.5 * end_error(off)
    again = _box_run(box_loop, True)
    np.testing.assert_array_equal(again.trajectory()[2], on.trajectory()[2])  # same bytes
    rec = json.loads(json.dumps([x.to_dict() for x in on.loops]))
    assert rec[0]["frames"] == [lp.frame, lp.loop_frame]


def test_run_json_has_the_loop_fields_and_the_switch_turns_them_off(vocab_file, tmp_path, monkeypatch, capsys):
    from d2slam.cli import main
    from d2slam.slam.fixture import write_room_sequence

    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    room = write_room_sequence(tmp_path / "room", n=12, seed=1, fps=10.0)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(f"engine:\n  vocabulary: {vocab_file}\n")

    def run(*extra):
        out, js = tmp_path / "t.txt", tmp_path / "t.json"
        assert main(["run", str(room), "--camera", "fr3", "--out", str(out), "--metrics-json", str(js), "--quiet",
                     "--config", str(cfg), *extra]) == 0
        return out.read_bytes(), json.loads(js.read_text())

    traj_on, on = run()
    assert on["loop_closing"] is True and on["loops"] == [] and on["loops_true"] == [] and on["loops_false"] == []
    assert on["vocabulary"]["path"] == str(vocab_file.resolve()) and on["loop_closest_call"] is None
    assert on["loop_detect_ms"] > 0 and on["loop_correct_s"] == [] and "loop_ms" in on
    traj_off, off = run("--no-loop-closing")
    assert off["loop_closing"] is False and "loops" not in off and off["config"]["engine"]["loop_closing"] is False
    assert traj_off == traj_on  # no loop, no relocalisation: the same trajectory
    assert main(["run", str(room), "--method", "orbslam3", "--out", str(tmp_path / "o.txt"),
                 "--no-loop-closing"]) == 2
    assert "--no-loop-closing does not apply" in capsys.readouterr().err


# ------------------------------------------------------------------ the scenario with a return, in the study
def test_office_loop_returns_home_after_twenty_seconds_through_every_wall():
    from d2slam.synth.scene import LOOP_RETURN, CameraPath, default_frames, resolve_frames

    n = default_frames("office_loop")
    assert n == 1200 and resolve_frames("office_loop", None) == 1200 and resolve_frames("office_loop", "tum") == 1200
    assert resolve_frames("walking_xyz", None) == 300
    duration = n / 30.0
    path = CameraPath("office_loop", np.random.default_rng([0, 3, 7]), duration)
    t = np.arange(n) / 30.0
    T = path.poses(t)
    home = T[0]
    back = int(np.argmax(path.loop_angle(t) >= 2 * np.pi))
    assert t[back] >= 20.0 and np.isclose(t[back], LOOP_RETURN * duration, atol=0.05)
    assert np.linalg.norm(T[back, :3, 3] - home[:3, 3]) < 0.1  # where it started (a few cm of height bob)
    axes = T[:, :3, 2]
    assert np.degrees(np.arccos(np.clip(axes[back] @ home[:3, 2], -1, 1))) < 8.0  # looking the same way
    heading = np.degrees(np.arctan2(axes[:back, 0], axes[:back, 1])) % 360
    assert np.histogram(heading, bins=8, range=(0, 360))[0].min() > 0  # it faced every direction on the way
    assert path.loop_angle(t[-1]) > 2 * np.pi + np.radians(90)  # and goes on round the loop


def test_study_grid_runs_the_return_scenario_with_loop_closing_on_and_off():
    from d2slam.study.grid import expand_grid

    specs = expand_grid(["office_loop"], seeds=[5], frames=40)
    dyn = [(s.method, s.loop_closing) for s in specs if not s.twin]
    assert sorted(dyn[:3]) == [("d2slam", True), ("none", True), ("oracle", True)]  # on, then off
    assert sorted(dyn[3:]) == [("d2slam", False), ("none", False), ("oracle", False)]
    assert all(s.frames == 1200 for s in specs)  # its own length, whatever --frames
    assert {(s.method, s.loop_closing) for s in specs if s.twin} == {("none", True), ("d2slam", True),
                                                                      ("oracle", True)}
    ids = [s.run_id for s in specs]
    assert len(set(ids)) == len(ids) and "office_loop_s5_n1200_d2slam_noloop" in ids


def test_tables_have_a_loop_closing_section():
    from d2slam.study.tables import loop_markdown, runs_frame, tables_markdown

    rows = []
    for seed in (1, 2):
        for m, on, ate, loops in (("none", 1, 0.05, (2, 1, 1)), ("none", 0, 0.06, None),
                                  ("d2slam", 1, 0.004, (1, 1, 0)), ("d2slam", 0, 0.008, None)):
            row = {"scenario": "office_loop", "sequence": "loop (ours)", "twin": 0, "method": m, "seed": seed,
                   "frames": 1200, "source": "synth", "loop_closing": on, "status": "ok", "ate_rmse_m": ate}
            if loops:
                row.update(loops=loops[0], loops_true=loops[1], loops_false=loops[2], loop_closest_ratio=1.5 + seed)
            rows.append(row)
    df = runs_frame(rows)
    md = loop_markdown(df)
    assert "| loop (ours) | `d2slam` | 0.0040 [0.0040, 0.0040] | 0.0080 [0.0080, 0.0080] | 0.50 [0.50, 0.50] | 2 | 2 " \
           "| 0 | 3.50 |" in md
    assert "| loop (ours) | `none` |" in md and "| 4 | 2 | 2 |" in md
    full = tables_markdown(df, ["none", "d2slam"], None)
    assert "## Loop closing: the scenario with a return (ours)" in full


def test_the_ablation_puts_dynamic_keypoints_back_into_words_and_matches(voc):
    d, dyn = _descriptors_with_dynamic()
    m = Map()
    db = KeyFrameDatabase(voc, m, _cfg(loops={"loop_dynamic_keypoints": True}).engine)
    m.add_keyframe(_kf(0, d, dynamic=dyn))
    np.testing.assert_array_equal(db.add(m.keyframes[0]).words, voc.bow(d, 2)[0])
    mp, proj, (cand, cur), _, _ = _pair(outliers=0.0)
    cur.desc = cand.desc.copy()
    cur.dynamic = np.zeros(len(cur.kps), bool)
    cur.dynamic[::3] = True
    cfg = _cfg(loops={"loop_dynamic_keypoints": True})
    lc = LoopCloser(mp, proj, cfg, voc, LocalMapper(mp, proj, cfg))
    lc.db.add(cand)
    lc.db.add(cur)
    geo, _ = lc.geometry(cur, cand)
    assert cur.dynamic[geo.kp].any()


def test_study_runs_record_loop_closing_and_its_loops():
    from d2slam.study.grid import RunSpec
    from d2slam.study.keys import run_key
    from d2slam.study.runner import execute_run, run_options
    from d2slam.study.sequences import ensure_sequence

    ensure_sequence("sitting_static", 101, 40, False)  # the sequence test_study_run uses (cached)
    on, off = RunSpec("sitting_static", "none", 101, 40), RunSpec("sitting_static", "none", 101, 40, loop_closing=False)
    assert RunSpec(**off.to_dict()) == off and off.run_id == on.run_id + "_noloop"
    opts = run_options()
    assert run_key(on, opts) != run_key(off, opts)
    a, b = execute_run(on, opts), execute_run(off, opts)
    assert a["row"]["status"] == b["row"]["status"] == "ok"
    assert a["row"]["loop_closing"] == 1 and a["row"]["loops"] == 0 and a["row"]["loops_false"] == 0
    assert a["loops"]["loop_closing"] is True and a["loops"]["loops"] == []
    assert b["row"]["loop_closing"] == 0 and "loops" not in b["row"] and b["loops"] == {"loop_closing": False}


def test_relocalisation_takes_its_candidates_from_the_database(box_loop, monkeypatch, tmp_path):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path))
    frames, poses, path = box_loop
    cfg = overridden(DEFAULT, {"orb": {"n_features": 500},
                               "engine": {"vocabulary": str(path), "tracking": {"init_min_keypoints": 200},
                                          "keyframes": {"kf_max_frames": 4}}})
    eng = Engine(CAM, cfg)
    for i in range(30):
        assert eng.process(*frames[i], i, i / 30.0).tracked
    asked = []
    query = eng.loop.db.relocalisation_candidates
    monkeypatch.setattr(eng.loop.db, "relocalisation_candidates", lambda *a: asked.append(query(*a)) or asked[-1])
    blank = (np.full_like(frames[0][0], 128), frames[0][1])
    assert eng.process(*blank, 30, 1.0).state == "lost"
    r = eng.process(*frames[5], 31, 31 / 30.0)  # back at an early view
    assert r.tracked and r.how == "relocalisation" and asked and asked[0]
    assert eng.map.keyframes[asked[0][0]].frame_index < 15  # the database's best candidate shows that view
