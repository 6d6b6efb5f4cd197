"""Place recognition on real frames: the shipped vocabulary + KeyframeDatabase on TUM fr1/rpy.

Keyframe-like samples: every 5th frame of the 300 fr1/rpy frames in the shared data (60
samples, 6 Hz). Each sample queries a database holding the earlier samples, of which those
within 1 s are excluded (neighbours always look alike; a loop/relocalisation search must
find a place seen *before*). A retrieval is correct when the motion-capture poses of the two
views overlap: optical axes within 20 degrees and optical centres within 0.3 m.

- precision@1: correct top-1 answers / queries answered (every query gets an answer: no
  score threshold, so queries without any overlapping earlier view count as wrong).
- recall: correct top-1 answers / queries that have at least one overlapping earlier view.
- chance: the mean fraction of overlapping views among a query's candidates, i.e. the
  precision a random pick would reach on the queries with a true match.

fr1/rpy only rotates (<= 0.17 m of translation), so the position test always passes and
overlap is decided by viewing direction; the camera sweeps back and forth, so most queries
have a true match. The vocabulary never saw these frames (python/ferroslam/vocabulary/README.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from ferroslam.datasets import TumSequence
from ferroslam.metrics import associate

vocabulary = pytest.importorskip("ferroslam.vocabulary")

STEP = 5
MIN_SEPARATION_S = 1.0
MAX_AXIS_ANGLE_DEG = 20.0
MAX_DISTANCE_M = 0.3

# Measured with the shipped vocabulary (sha256 effe5349...) and 1000 ORB features per frame:
# 53 queries, 43 with an overlapping earlier view, 34 correct top-1 -> precision@1 0.642,
# recall 0.791, chance 0.273. 6 of the 9 misses on queries with a true match are near misses
# (axes 20-28 degrees apart). The pipeline is deterministic for a given build; the bounds
# leave room for ~4-5 queries to flip (one query moves precision by 1.9 and recall by
# 2.3 points), e.g. from another OpenCV/JPEG decoder build changing a few keypoints, while
# a broken vocabulary, database or scoring (which falls to chance, ~0.27) fails.
PRECISION_AT_1_MIN = 0.55
RECALL_MIN = 0.70
CHANCE_FACTOR_MIN = 2.0


def _overlap(T_a: np.ndarray, T_b: np.ndarray) -> bool:
    cos = float(np.clip(T_a[:3, 2] @ T_b[:3, 2], -1.0, 1.0))
    return (np.degrees(np.arccos(cos)) < MAX_AXIS_ANGLE_DEG
            and np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) < MAX_DISTANCE_M)


@pytest.fixture(scope="module")
def retrievals(tum_rpy):
    """Per query: (top-1 id or None, seconds between query and top-1, has a true match,
    top-1 correct, chance)."""
    seq = TumSequence(tum_rpy, with_depth=False)
    frames = np.arange(0, len(seq), STEP)
    times = seq.timestamps[frames]
    gt_t, gt_T = seq.groundtruth()
    i_gt, i_s = associate(gt_t, times, max_diff=0.02)
    assert len(i_s) == len(frames), "ground truth must cover every sample"
    poses = np.empty((len(frames), 4, 4))
    poses[i_s] = gt_T[i_gt]
    descriptors = vocabulary.extract_descriptors(seq[int(f)].rgb_path for f in frames)

    db = vocabulary.KeyframeDatabase(vocabulary.default_vocabulary())
    rows = []
    for q in range(len(frames)):
        candidates = [p for p in range(q) if times[q] - times[p] > MIN_SEPARATION_S]
        if candidates:
            neighbours = set(range(q)) - set(candidates)
            top = db.query(descriptors[q], max_results=1, exclude=neighbours)
            truth = [_overlap(poses[q], poses[p]) for p in candidates]
            best = top[0][0] if top else None
            correct = best is not None and _overlap(poses[q], poses[best])
            gap = times[q] - times[best] if best is not None else None
            rows.append((best, gap, any(truth), correct, float(np.mean(truth))))
        db.add(q, descriptors[q])
    return rows


def test_precision_and_recall_on_fr1_rpy(retrievals):
    answered = [r for r in retrievals if r[0] is not None]
    with_truth = [r for r in retrievals if r[2]]
    correct = sum(r[3] for r in answered)
    precision = correct / len(answered)
    recall = correct / len(with_truth)
    chance = float(np.mean([r[4] for r in with_truth]))
    print(f"\nplace recognition on fr1/rpy: {len(retrievals)} queries, {len(answered)} answered, "
          f"{len(with_truth)} with an overlapping earlier view; {correct} correct top-1: "
          f"precision@1 {precision:.3f}, recall {recall:.3f} (chance {chance:.3f})")
    assert len(retrievals) == 53 and len(answered) == 53
    assert len(with_truth) >= 40  # geometry of the test set, from the ground truth alone
    assert precision >= PRECISION_AT_1_MIN
    assert recall >= RECALL_MIN
    assert recall >= CHANCE_FACTOR_MIN * chance


def test_never_retrieves_an_excluded_neighbour(retrievals):
    gaps = [gap for _, gap, *_ in retrievals if gap is not None]
    assert gaps and min(gaps) > MIN_SEPARATION_S
