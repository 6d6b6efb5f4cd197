"""Command line: ``ferroslam demo`` (the bundled sample), ``ferroslam run`` (track a sequence),
``ferroslam eval ate|rpe``, ``ferroslam download`` (public datasets), ``ferroslam vocab`` and
``ferroslam check`` (what would make a run fail, before it).

``build_parser()`` is separate from ``main()`` so the parser is testable without a process.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import traceback
from pathlib import Path
from typing import Optional, Sequence

from .metrics import ALIGNMENTS
from ._files import StagedFolder
from .outputs import write_run_outputs
from .pipeline import SENSORS

__all__ = ["build_parser", "main"]


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _non_negative_int(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text}")
    return value


def _positive_rate(text: str) -> float:
    value = float(text)
    if not (0 < value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number of frames per second, "
                                         f"got {text}")
    return value


def _non_negative_seconds(text: str) -> float:
    value = float(text)
    if not (value >= 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a number of seconds >= 0, got {text}")
    return value


def _depth_scale(text: str) -> float:
    from .options import check_option

    try:
        return float(check_option("depth_scale", float(text)))
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _topic_list(text: str) -> list[str]:
    topics = [t.strip() for t in text.split(",") if t.strip()]
    if not topics:
        raise argparse.ArgumentTypeError(f"expected topic names separated by commas, got "
                                         f"{text!r}")
    return topics


def _add_eval_inputs(p: argparse.ArgumentParser, default_align: str) -> None:
    p.add_argument("ref", type=Path, help="reference (ground-truth) trajectory file")
    p.add_argument("est", type=Path, help="estimated trajectory file")
    p.add_argument("--format", choices=("tum", "kitti"), default="tum",
                   help="file format of both files (default: tum)")
    p.add_argument("--align", choices=ALIGNMENTS, default=default_align,
                   help=f"alignment of the estimate (default: {default_align})")
    p.add_argument("--max-diff", type=_non_negative_seconds, default=0.01,
                   help="timestamp association tolerance in seconds (default: 0.01)")


_EPILOG = """\
examples:
  ferroslam demo                                  RGB-D SLAM on the bundled TUM sample
  ferroslam download tum freiburg1_xyz --to data  fetch a full TUM sequence (~0.5 GB)
  ferroslam check data/rgbd_dataset_freiburg1_xyz --sensor rgbd
  ferroslam run data/rgbd_dataset_freiburg1_xyz --sensor rgbd
  ferroslam eval ate groundtruth.txt out/rgbd_dataset_freiburg1_xyz/trajectory.txt

Every command has its own help: ferroslam COMMAND --help"""

_OUTPUTS = """\
outputs (in --out):
  trajectory.txt      the tracked frames of the largest map (most frames; ties: the older), in
                      its frame; TUM format (timestamp tx ty tz qx qy qz qw, T_w_c);
                      --trajectory-format kitti / euroc (trajectory.csv) for the others
  keyframes.txt       keyframe poses of the map trajectory.txt holds, same format
  maps/map_<id>.txt   each map's tracked frames in its own frame, same format (a monocular run
                      starts a new map, id 1, 2, ..., after its map stays lost; one file with
                      one map)
  colmap/             COLMAP model of that map: images/ (its keyframes' images), sparse/0/
                      (cameras, images with their 2-D points, points with their tracks; text)
  mesh.ply, dense.ply with --dense (rgbd): TSDF mesh and dense cloud of the keyframes
  map.ply             that map's points (world frame = first camera, metres), PLY
  plot.png            top and side views against the ground truth, map points
  trajectory_top.png  top view only
  results.json        settings, tracking states, timings, ATE/RPE, "maps" (id, frames,
                      keyframes: null for a map closed during the run) and
                      "trajectory_map" (the id trajectory.txt holds)"""

_LAYOUTS = """\
dataset layouts (--format auto detects them):
  tum    PATH/rgb.txt, depth.txt, groundtruth.txt (optional); the camera from the folder name
         (freiburg1/2/3 or fr1/2/3), PATH/camera.yaml or --camera
  kitti  PATH/image_0/ (and image_1/ for stereo), calib.txt, times.txt; ground truth
         poses.txt or ../../poses/NN.txt (optional)
  euroc  PATH/mav0/cam0/ (and cam1/): data.csv, data/, sensor.yaml; ground truth
         mav0/state_groundtruth_estimate0/data.csv (optional)

ROS bags (.bag, a ROS 2 bag folder, .mcap; pip install 'ferroslam[ros]'; no ground truth):
  images, depth, CameraInfo and IMU topics found by type and name (or --topics); the
  calibration from CameraInfo or --camera (stereo: --camera with the rig's extrinsics, e.g. a
  Kalibr camchain); the IMU noise model from --imu

other sources (--sensor mono, --camera FILE; no ground truth, so no ATE):
  video     a video file OpenCV reads (.mp4, .avi, ...); frame times from the stream
  images    a folder of .png/.jpg, in name order; times from numeric names (seconds, or
            nanoseconds as 1403636579763555584.png) or from --fps
  camera:N  live camera N (OpenCV's numbering: /dev/videoN); frames that come while
            tracking is behind are dropped; Ctrl+C ends the run and writes the results"""


def _add_output_options(p: argparse.ArgumentParser, default_out: str) -> None:
    from .export import TRAJECTORY_FORMATS

    output = p.add_argument_group("output")
    output.add_argument("--out", type=Path, help=f"output folder (default: {default_out})")
    output.add_argument("--viewer", action="store_true",
                        help="show the run live in the Rerun viewer (pip install "
                             "'ferroslam[viewer]')")
    output.add_argument("--rerun-save", type=Path, metavar="FILE.rrd",
                        help="record the run for the Rerun viewer to FILE.rrd (headless)")
    output.add_argument("--trajectory-format", choices=TRAJECTORY_FORMATS, default="tum",
                        help="format of trajectory.txt and keyframes.txt: tum (default), kitti "
                             "(3x4 rows, no time) or euroc (ASL csv, .csv files)")
    output.add_argument("--silent", action="store_true", help="no progress bar, no summary")


def build_parser() -> argparse.ArgumentParser:
    """The ``ferroslam`` argument parser (``demo``, ``run``, ``eval {ate,rpe}``, ``download``,
    ``vocab {train,export-dbow2}``, ``batch``, ``check``)."""
    from .demo import DEMO_CONFIGS
    from .download import DATASETS

    parser = argparse.ArgumentParser(
        prog="ferroslam", description="Visual SLAM (ORB-SLAM pipeline) with a Rust core.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    parser.add_argument("--traceback", action="store_true",
                        help="on an error, print the stack too (or FERROSLAM_TRACEBACK=1)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = sub.add_parser(
        "demo", help="run SLAM on the bundled TUM sample (no download needed)",
        description="Track the 90 RGB-D frames of TUM fr1/rpy shipped with ferroslam\n"
                    "(3 s of hand-held rotation; CC BY 4.0, Sturm et al., IROS 2012), print\n"
                    "ATE and time per frame, and write the results to --out.",
        epilog=_OUTPUTS, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    demo.add_argument("--sensor", choices=tuple(DEMO_CONFIGS), default="rgbd",
                      help="rgbd (default) or mono (same frames, colour only; scale-free, "
                           "so ATE after Sim(3) alignment). The sample has no stereo pair.")
    demo.add_argument("--max-frames", type=_positive_int,
                      help="process only the first N of the 90 frames")
    demo.add_argument("--seed", type=int, help="random seed")
    _add_output_options(demo, "./ferroslam-demo")

    run = sub.add_parser(
        "run", help="track a dataset sequence and evaluate it",
        description="Track a sequence folder frame by frame; with ground truth, print\n"
                    "ATE/RPE, and write the results to --out.",
        epilog=_LAYOUTS + "\n\n" + _OUTPUTS, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run.add_argument("path", type=Path,
                     help="sequence folder (TUM RGB-D, KITTI odometry or EuRoC (ASL) layout), "
                          "ROS bag (.bag, ROS 2 folder, .mcap), video file, image folder or "
                          "camera:N")
    algo = run.add_argument_group("algorithm")
    algo.add_argument("--sensor", choices=SENSORS, required=True,
                      help="camera setup: mono (any layout), rgbd (TUM, bags), stereo (KITTI, "
                           "EuRoC, bags), rig (EuRoC cam0 + cam1 raw, matched along epipolar "
                           "curves, no rectification); -inertial adds the IMU (EuRoC, bags)")
    algo.add_argument("--config", type=Path,
                      help="JSON file of SlamSystem/extractor options, e.g. "
                           '{"n_features": 2000, "depth_threshold": 35}')
    algo.add_argument("--seed", type=int, help="random seed (overrides the config's 'seed')")
    algo.add_argument("--max-frames", type=_positive_int, help="process only the first N frames")
    algo.add_argument("--first-frame", type=_non_negative_int, default=0, metavar="N",
                      help="start at frame N of the sequence (a later session)")
    algo.add_argument("--map", type=Path, metavar="PRIOR.map", dest="prior_map",
                      help="map onward from a saved map (an earlier session): the run "
                           "relocalises in it or merges into it once it recognises it")
    algo.add_argument("--save-map", type=Path, metavar="OUT.map",
                      help="write the run's maps (the whole atlas) to this file at the end")
    algo.add_argument("--no-stereo", action="store_true",
                      help="rig: match cameras 0 and 1 only at keyframes, where their keypoints "
                           "are triangulated across the rig (no per-frame stereo matching)")
    algo.add_argument("--dense", action="store_true",
                      help="rgbd: fuse the keyframes' depth into mesh.ply and dense.ply (TSDF, "
                           "pip install 'ferroslam[dense]'; voxel and truncation: the "
                           "dense_voxel_m, dense_truncation_m options of --config)")
    _add_input_options(run)
    _add_output_options(run, "out/<sequence name>")

    ev = sub.add_parser("eval", help="evaluate trajectory files",
                        description="Compare an estimated trajectory file with a reference.")
    ev_sub = ev.add_subparsers(dest="metric", metavar="METRIC", required=True)
    ate_p = ev_sub.add_parser("ate", help="absolute trajectory error (translation, metres)",
                              description="Absolute trajectory error after alignment "
                                          "(translation RMSE etc., metres).")
    _add_eval_inputs(ate_p, "se3")
    rpe_p = ev_sub.add_parser("rpe", help="relative pose error over --delta frames",
                              description="Relative pose error over --delta frames "
                                          "(translation metres, rotation degrees).")
    _add_eval_inputs(rpe_p, "none")
    rpe_p.add_argument("--delta", type=_positive_int, default=1, help="frames (default: 1)")

    dl = sub.add_parser(
        "download", help="download and extract a public dataset sequence",
        description="Fetch a sequence from its official server (TUM .tgz, EuRoC ASL .zip)\n"
                    "with a progress bar, resume of an interrupted download (HTTP Range), a\n"
                    "size check (and sha256 if given), and extract it into --to. KITTI needs\n"
                    "a login: the command prints the steps and exits with status 3.",
        epilog="names:\n"
               "  tum    freiburg1_xyz, fr2_desk, rgbd_dataset_freiburg3_long_office_household\n"
               "         (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download)\n"
               "  euroc  MH_01_easy ... MH_05_difficult, V1_01_easy ... V2_03_difficult\n"
               "         (a prefix such as V1_01 is enough)\n"
               "  kitti  00 ... 21 (odometry; instructions only)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    dl.add_argument("dataset", choices=DATASETS, help="which benchmark")
    dl.add_argument("name", help="sequence name (see below)")
    dl.add_argument("--to", type=Path, required=True, metavar="DIR",
                    help="destination folder (created); the archive is kept there while "
                         "downloading so an interrupted run resumes")
    dl.add_argument("--url", help="download from this address instead (a mirror)")
    dl.add_argument("--sha256", metavar="HEX",
                    help="expected SHA-256 of the archive (required for plain-http sources "
                         "such as EuRoC's official server)")
    dl.add_argument("--keep-archive", action="store_true",
                    help="keep the archive after extraction")
    dl.add_argument("--timeout", type=float, default=30.0,
                    help="network timeout in seconds (default: 30)")
    dl.add_argument("--silent", action="store_true", help="no progress bar")
    _add_vocab_parser(sub)
    _add_batch_parser(sub)
    _add_check_parser(sub)
    _add_export_parser(sub)
    _add_merge_parser(sub)
    _add_fleet_parser(sub)
    return parser


def _add_input_options(parser: argparse.ArgumentParser) -> None:
    """How PATH is read, the same for ``run`` and ``check``."""
    source = parser.add_argument_group("calibration and input")
    source.add_argument("--format", choices=("auto", "tum", "kitti", "euroc"), default="auto",
                        help="dataset layout (default: detect)")
    source.add_argument("--camera", type=Path, metavar="FILE",
                        help="calibration: ORB-SLAM3 settings, Kalibr camchain, OpenCV or ROS "
                             "camera_info, flat camera.yaml; required for videos, image "
                             "folders and cameras, replaces a dataset folder's own, and a "
                             "bag's CameraInfo")
    source.add_argument("--depth-scale", type=_depth_scale, metavar="FACTOR",
                        help="depth pixel value per metre of RGB-D depth (TUM 5000, "
                             "millimetres 1000); default: the calibration's DepthMapFactor / "
                             "depth_scale, else the layout's")
    source.add_argument("--fps", type=_positive_rate,
                        help="frame rate of an image folder (frame i at i/fps s), for names "
                             "that are not times")
    source.add_argument("--topics", type=_topic_list, metavar="T1,T2,...",
                        help="ROS bag: the topics to read, left before right (default: found "
                             "by type and name)")
    source.add_argument("--mask", type=Path, metavar="FILE",
                        help="static keypoint mask: a grey image of the tracked images' size "
                             "(rectified, for a stereo dataset), 0 = no features there; "
                             "replaces the calibration's own")
    source.add_argument("--imu", type=Path, metavar="FILE",
                        help="ROS bag: the IMU noise model (Kalibr imu.yaml, EuRoC "
                             "sensor.yaml, ORB-SLAM3 settings), for -inertial sensors")


def _add_check_parser(sub: argparse._SubParsersAction) -> None:
    """``check``: what would make a run fail, before it (``ferroslam.check``)."""
    check = sub.add_parser(
        "check", help="check a sequence and its calibration before running it",
        description="Check PATH as 'ferroslam run' would read it: image sizes against the\n"
                    "calibration, the distortion over the whole image, frame times, the depth\n"
                    "scale, the IMU (rate, gaps, units, gravity, noise) and the camera-IMU\n"
                    "time offset (from a visual-only run over the first 10 s). One line per\n"
                    "check: ok, warning or error, and what to do. Exit status 1 on an error.",
        epilog=_LAYOUTS, formatter_class=argparse.RawDescriptionHelpFormatter)
    check.add_argument("path", type=Path, help="what 'ferroslam run' takes")
    check.add_argument("--sensor", choices=SENSORS,
                       help="the setup to check for (default: all the input holds: depth, "
                            "stereo pairs, IMU)")
    _add_input_options(check)
    check.add_argument("--json", action="store_true",
                       help="print only JSON: the checks and imu_time_offset_s (seconds)")


def _add_export_parser(sub: argparse._SubParsersAction) -> None:
    """``export MAP --colmap DIR``: a saved map as a COLMAP model."""
    export = sub.add_parser(
        "export", help="write a saved map as a COLMAP model",
        description="Write the keyframes, keypoints, points and tracks of a map file\n"
                    "(save_map) as a COLMAP text model in DIR/sparse/0/. A map file holds no\n"
                    "images: DIR/image_timestamps.txt names the source frame of each image.")
    export.add_argument("map", type=Path, help="map file")
    export.add_argument("--colmap", type=Path, required=True, metavar="DIR",
                        help="output folder (created)")


def _add_vocab_parser(sub: argparse._SubParsersAction) -> None:
    """``vocab train`` and ``vocab export-dbow2`` (place-recognition vocabularies)."""
    voc = sub.add_parser("vocab", help="train or export an ORB vocabulary")
    voc_sub = voc.add_subparsers(dest="vocab_command", metavar="ACTION", required=True)
    train = voc_sub.add_parser("train", help="train a vocabulary on images")
    train.add_argument("images", nargs="+", type=Path,
                       help="image files or folders (every .png/.jpg/... inside, sorted)")
    train.add_argument("--k", type=_positive_int, default=10, help="branching factor (default: 10)")
    train.add_argument("--levels", type=_positive_int, default=5, help="tree depth (default: 5)")
    train.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    train.add_argument("--step", type=_positive_int, default=1,
                       help="keep every N-th image of each folder (default: 1)")
    train.add_argument("--features", type=_positive_int, default=1000,
                       help="ORB features per image (default: 1000)")
    train.add_argument("--out", type=Path, required=True, help="binary vocabulary to write")
    train.add_argument("--text", type=Path, help="also write DBoW2 text (ORBvoc.txt format)")
    export = voc_sub.add_parser("export-dbow2",
                                help="write a vocabulary as DBoW2 text for ORB-SLAM2/3")
    export.add_argument("out", type=Path, help="text file to write")
    export.add_argument("--vocabulary", type=Path,
                        help="binary vocabulary to export (default: the shipped one)")


def _add_batch_parser(sub: argparse._SubParsersAction) -> None:
    """``batch``: a SPEC of runs fanned out over a Ray cluster (``ferroslam.batch``)."""
    from .batch import SPEC_EXAMPLE

    batch = sub.add_parser(
        "batch", help="run sequences x option sets x repeats over a Ray cluster",
        description="Run every sequence x option set x repeat of SPEC as one Ray task, each\n"
                    "in its own folder of DIR (what 'ferroslam run' writes), then write\n"
                    "DIR/results.csv (one row per run) and DIR/summary.md (median, min-max\n"
                    "over repeats). Runs already done in DIR are skipped. Exit status 1 if\n"
                    "any run failed. Needs Ray: pip install 'ferroslam[batch]'.",
        epilog="SPEC (JSON or YAML; top-level keys are defaults that a run's keys override,\n"
               "'grid' sweeps every combination, relative folders are relative to SPEC):\n"
               + SPEC_EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    batch.add_argument("spec", type=Path, help="JSON or YAML file of runs (below)")
    batch.add_argument("--out", type=Path, required=True, metavar="DIR",
                       help="output folder (created); holds one folder per run")
    cluster = batch.add_argument_group("cluster")
    cluster.add_argument("--address", metavar="ADDR",
                         help="existing Ray cluster: auto, HOST:PORT or ray://HOST:PORT "
                              "(default: start a local one on 127.0.0.1, stopped at the end)")
    cluster.add_argument("--num-cpus", type=_positive_int, metavar="N",
                         help="CPUs of the local Ray instance (default: all)")
    cluster.add_argument("--cpus-per-run", type=_positive_int, default=1, metavar="N",
                         help="CPUs (and Rayon threads) of each run (default: 1)")
    batch.add_argument("--retry-failed", action="store_true",
                       help="run the failed runs of an earlier call again")
    batch.add_argument("--silent", action="store_true", help="no progress bar, no summary")


def _add_merge_parser(sub: argparse._SubParsersAction) -> None:
    """``merge``: saved maps merged where they overlap (``ferroslam.fleet.merge_maps``)."""
    merge = sub.add_parser(
        "merge", help="merge saved maps (sessions) where they overlap",
        description="Merge the maps of the map files (save_map / --save-map of the sessions)\n"
                    "where they overlap and write every map left, merged or not, to\n"
                    "MERGED.map. All inputs must come from the same sensor and camera. With\n"
                    "--trajectory (one TUM file per input), each input's trajectory is written\n"
                    "in the frame of the map the input's last map ended in.")
    merge.add_argument("maps", nargs="*", type=Path, metavar="MAP", help="map files")
    merge.add_argument("-o", "--output", type=Path, required=True, metavar="MERGED.map",
                       help="atlas file to write")
    merge.add_argument("--trajectory", nargs="+", type=Path, metavar="TRAJ",
                       help="one TUM trajectory per input, in input order (e.g. each "
                            "session's trajectory.txt)")
    merge.add_argument("--out-trajectories", type=Path, metavar="DIR",
                       help="folder of the re-expressed trajectories, DIR/<map stem>.txt "
                            "(default: <MERGED stem>_trajectories next to MERGED.map)")


def _add_fleet_parser(sub: argparse._SubParsersAction) -> None:
    """``fleet``: sessions mapped as Ray tasks, then merged as a tree of Ray tasks."""
    from .fleet import FLEET_SPEC_EXAMPLE

    fleet = sub.add_parser(
        "fleet", help="map sessions in parallel on Ray and merge their maps",
        description="Map each run of SPEC (one session: a sequence, or a part of it with\n"
                    "first_frame and max_frames) as one Ray task, then merge the maps\n"
                    "pairwise as a tree of Ray tasks, within groups of the same sensor and\n"
                    "camera. Writes DIR/merged.map (the largest group; merged_<k>.map the\n"
                    "others), DIR/<run>/trajectory_merged.txt and DIR/summary.json. Needs Ray:\n"
                    "pip install 'ferroslam[batch]'.",
        epilog="SPEC (JSON or YAML): the format of 'ferroslam batch' (each run one session;\n"
               "no repeats, no grid), plus 'first_frame' (top level or per run):\n"
               + FLEET_SPEC_EXAMPLE,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    fleet.add_argument("spec", type=Path, help="JSON or YAML file of runs")
    fleet.add_argument("--out", type=Path, required=True, metavar="DIR",
                       help="output folder (created)")
    cluster = fleet.add_argument_group("cluster")
    cluster.add_argument("--address", metavar="ADDR",
                         help="existing Ray cluster: auto, HOST:PORT or ray://HOST:PORT "
                              "(default: start a local one on 127.0.0.1, stopped at the end)")
    cluster.add_argument("--num-cpus", type=_positive_int, metavar="N",
                         help="CPUs of the local Ray instance (default: all)")
    fleet.add_argument("--silent", action="store_true", help="no progress, no summary")


def _load_config(path: Optional[Path]) -> dict:
    """The ``--config`` object (JSON, or YAML for other names), size- and depth-bounded before
    parsing by the options module's loader."""
    if path is None:
        return {}
    from .options import load_option_file

    config = load_option_file(path)
    if "track_feature_range" in config:  # JSON has no tuples
        config["track_feature_range"] = tuple(config["track_feature_range"])
    return config


def _open_input(args: argparse.Namespace):
    """:func:`_open_data`, with ``--mask`` the tracked camera's static keypoint mask."""
    data, notes = _open_data(args)
    if args.mask is not None:
        from .calibration import load_mask

        data.camera = data.camera.with_mask(load_mask(args.mask))
        notes.append(f"static mask from {args.mask}")
    return data, notes


def _open_data(args: argparse.Namespace):
    """The dataset sequence, bag, or video / image folder / camera source ``args.path``
    names, and the notes on it for the summary; ``--camera`` is a source's calibration and
    replaces a dataset folder's or a bag's own."""
    from .bags import is_bag, open_bag
    from .calibration import load_calibration
    from .datasets import detect_format, is_sequence_folder, open_sequence
    from .sources import open_source

    bag = is_bag(args.path)
    if not bag and (args.topics is not None or args.imu is not None):
        raise ValueError(f"--topics and --imu are for ROS bags; {args.path} is not one")
    if bag or args.format != "auto" or is_sequence_folder(args.path):
        if args.fps is not None:
            raise ValueError(f"--fps is for image folders; {args.path} has its own frame times")
        if bag:
            recording = open_bag(args.path, sensor=args.sensor, topics=args.topics,
                                 camera=args.camera, imu=args.imu, depth_scale=args.depth_scale)
            return recording, list(recording.notes)
        calibration = load_calibration(args.camera) if args.camera is not None else None
        seq = open_sequence(args.path, args.format, sensor=args.sensor, calibration=calibration,
                            depth_factor=args.depth_scale)
        notes = []
        if calibration is not None:
            layout = args.format if args.format != "auto" else detect_format(args.path)
            notes.append(f"calibration from {args.camera}, not the {layout} layout's own")
        depth_factor = getattr(seq, "depth_factor", None)
        if depth_factor is not None and args.sensor.startswith("rgbd"):
            notes.append(f"depth scale {depth_factor:g} pixel values per metre")
        return seq, notes
    _check_camera_index(str(args.path))
    if args.depth_scale is not None:
        raise ValueError(f"--depth-scale is for RGB-D folders and bags; {args.path} has no depth")
    if args.sensor != "mono":
        try:
            open_sequence(args.path, sensor=args.sensor)  # says which layouts it looked for
        except (OSError, ValueError) as err:
            raise type(err)(f"{err}; videos, image folders and camera:N are read with "
                            "--sensor mono") from None
    source = open_source(args.path, fps=args.fps)
    if args.camera is None:
        raise ValueError(f"{args.path}: a video, image folder or camera needs its calibration: "
                         "--camera FILE (ORB-SLAM3 settings, Kalibr camchain, OpenCV or ROS "
                         "camera_info, flat camera.yaml)")
    source.camera = load_calibration(args.camera).cameras[0]
    return source, []


# OpenCV takes a camera index as a C int.
_CAMERA_INDEX = re.compile(r"camera:(\d+)")
_MAX_CAMERA_INDEX = 2**31 - 1


def _check_camera_index(spec: str) -> None:
    match = _CAMERA_INDEX.fullmatch(spec)
    if match and int(match.group(1)) > _MAX_CAMERA_INDEX:
        raise ValueError(f"{spec}: camera index out of range (0..{_MAX_CAMERA_INDEX})")


def _cmd_run(args: argparse.Namespace) -> int:
    config = _load_config(args.config)
    if args.seed is not None:
        config["seed"] = args.seed
    if args.dense:
        config["dense"] = True
    if args.no_stereo:
        if args.sensor not in ("rig", "rig-inertial"):
            raise ValueError(f"--no-stereo is for --sensor rig (a stereo pair left raw), not "
                             f"--sensor {args.sensor}")
        config["match_pair_every_frame"] = False
    seq, notes = _open_input(args)
    from .check import require_cheap_checks

    require_cheap_checks(seq, args.sensor)
    out = args.out if args.out is not None else Path("out") / seq.name
    sessions = {"first_frame": args.first_frame, "prior_map": args.prior_map,
                "save_map": args.save_map}
    return _track_and_report(seq, args.sensor, config, args.max_frames, out, args.silent,
                             args.trajectory_format, _rerun_logger(args), notes, sessions)


def _cmd_check(args: argparse.Namespace) -> int:
    from .check import CheckReport, check_sequence, opening_error
    from .datasets import is_sequence_folder

    sensor = args.sensor
    if sensor is None:  # open a dataset with all it holds, anything else as run does
        dataset = args.format != "auto" or is_sequence_folder(args.path)
        args.sensor = "" if dataset else "mono"
    try:
        seq, _ = _open_input(args)
    except (OSError, ValueError) as err:
        report = CheckReport([opening_error(err)])
    else:
        report = check_sequence(seq, sensor)
    if args.json:
        print(json.dumps(report.to_json(), indent=2))
    else:
        for check in report.checks:
            print(check.line())
    return 1 if report.failed else 0


def _rerun_logger(args: argparse.Namespace):
    """A Rerun logger for ``--viewer`` (live) or ``--rerun-save FILE.rrd``, else None."""
    if not (args.viewer or args.rerun_save):
        return None
    from .viewer import RerunLogger

    if args.viewer and args.rerun_save:
        raise ValueError("--viewer and --rerun-save: choose one (the viewer can save what it "
                         "shows)")
    # JPEG keeps a recording of a whole run to tens of MB instead of hundreds.
    return RerunLogger(spawn=args.viewer, save_path=args.rerun_save, jpeg_quality=85)


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import DEMO_CONFIGS, sample_sequence

    config = dict(DEMO_CONFIGS[args.sensor])
    if args.seed is not None:
        config["seed"] = args.seed
    out = args.out if args.out is not None else Path("ferroslam-demo")
    if not args.silent:
        print(f"ferroslam demo: {args.sensor} SLAM on the bundled TUM fr1/rpy sample "
              "(CC BY 4.0, Sturm et al., IROS 2012)")
    with sample_sequence() as seq:
        return _track_and_report(seq, args.sensor, config, args.max_frames, out, args.silent,
                                 args.trajectory_format, _rerun_logger(args))


def _track_and_report(seq, sensor: str, config: dict, max_frames: Optional[int], out: Path,
                      silent: bool, trajectory_format: str = "tum", logger=None,
                      notes: Sequence[str] = (), sessions: Optional[dict] = None) -> int:
    """Run ``seq`` (a live source through ``run_source``), write every output file into a
    staging folder moved into ``out`` when the run is over, and print the summary. A run that
    stops at an error (a corrupt image at frame N, a bad ground-truth line) leaves the results
    of an earlier run in ``out`` as they were, puts the results of the frames before the error
    in ``out/partial-<UTC time>/``, then reports the error. ``sessions``: ``first_frame``,
    ``prior_map`` and ``save_map`` of :func:`~ferroslam.pipeline.run_sequence`."""
    from .pipeline import RunError, run_sequence, run_source

    sessions = {k: v for k, v in (sessions or {}).items() if v}
    if sessions and getattr(seq, "live", False):
        raise ValueError("--first-frame, --map and --save-map are for recorded sequences, not "
                         "a live source")

    on_frame = None
    if logger is not None:
        from .viewer import make_frame_callback

        on_frame = make_frame_callback(logger, seq.camera)
    stage = StagedFolder(out)  # an unwritable --out fails here, before tracking
    try:
        with stage:
            try:
                if getattr(seq, "live", False):
                    result = run_source(seq, config, max_frames=max_frames,
                                        progress=not silent)
                else:
                    result = run_sequence(seq, config, max_frames=max_frames,
                                          progress=not silent, sensor=sensor,
                                          on_frame=on_frame, **sessions)
            except RunError as err:
                write_run_outputs(err.partial, stage.path, trajectory_format)
                _log_final_map(logger, err.partial)
                raise
            _log_final_map(logger, result)
            summary = write_run_outputs(result, stage.path, trajectory_format)
    except RunError as err:
        raise RunError(f"{err}; the results of the {err.partial.frames} frames before it are "
                       f"in {stage.partial}/ (earlier results in {out}/ are kept)",
                       err.partial, err.frame) from err
    if not silent:
        _print_summary(summary, out, notes)
    return 0


def _log_final_map(logger, result) -> None:
    """The map as bundle adjustment and loop closing left it, to the Rerun logger (if any),
    which is then closed (a recording is complete only then)."""
    if logger is None:
        return
    with logger:
        logger.log_map(result.map_points, result.map_point_colors,
                       keyframe_poses_T_w_c=result.keyframes.poses, loops=result.loops,
                       keyframe_ids=result.keyframe_ids)
        if result.dense is not None:
            logger.log_mesh(result.dense)


def _maps_line(summary: dict) -> str:
    """How many maps the run made and which one the trajectory file holds (named without
    its suffix: .csv with --trajectory-format euroc)."""
    maps = summary["maps"]
    chosen = next(m for m in maps if m["id"] == summary["trajectory_map"])
    held = f"map {chosen['id']} ({chosen['frames']} frames"
    if len(maps) == 1:
        return f"1: {held}), the trajectory"
    return f"{len(maps)}; the trajectory holds {held}, the largest), maps/ each one"


def _print_summary(summary: dict, out: Path, notes: Sequence[str] = ()) -> None:
    print(f"sequence        {summary['sequence']}  ({summary['sensor']})")
    print(f"tracked frames  {summary['tracked_frames']}/{summary['frames']}  "
          f"keyframes {summary['keyframes']}  map points {summary['map_points']}")
    frame = summary["timing_ms"].get("frame_ms")
    if frame:
        print(f"time per frame  median {frame['median']:.1f} ms  p95 {frame['p95']:.1f} ms")
    latency = summary["timing_ms"].get("latency_ms")
    if latency:
        print(f"latency         median {latency['median']:.1f} ms  p95 {latency['p95']:.1f} ms"
              f"  ({summary['dropped_frames']} frames dropped while tracking was behind)")
    metrics = summary["metrics"]
    if summary["first_initialised_frame"] is None:
        print("status          not initialised: the map never started")
    elif summary["sensor"].startswith("mono"):
        print(f"initialised at  frame {summary['first_initialised_frame']}; "
              f"{100 * summary['tracked_after_init']:.1f} % of the later frames tracked, "
              f"{summary['num_maps']} map(s)")
    if summary.get("maps"):  # none when nothing was tracked
        print(f"maps            {_maps_line(summary)}")
    for name, label in (("ate_frames", "ATE frames"), ("ate_keyframes", "ATE keyframes")):
        if name in metrics:
            m = metrics[name]
            align = "Sim(3), largest map" if m["align"] == "sim3" else "SE(3)"
            print(f"{label:<15} RMSE {m['rmse']:.4f} m  ({align}, {m['pairs']} poses)")
    if "scale_error" in metrics:
        print(f"scale error     {100 * metrics['scale_error']:+.2f} %  (Sim(3) alignment's scale)")
    if "path_length" in metrics:
        p = metrics["path_length"]
        print(f"path length     {p['estimate_m']:.3f} m vs {p['reference_m']:.3f} m "
              "(longer with per-frame jitter)")
    if "rpe_frames" in metrics:
        r = metrics["rpe_frames"]
        print(f"RPE (1 frame)   {r['trans_rmse_m']:.4f} m  {r['rot_rmse_deg']:.3f} deg RMSE")
    inertial = summary.get("inertial")
    if inertial and inertial["status"] == "aligned":
        print(f"IMU alignment   scale {inertial['scale']:.4f}, gyro bias "
              f"({', '.join(f'{b:.4f}' for b in inertial['gyro_bias'])}) rad/s "
              f"(refinement {inertial['refinement']})")
    elif inertial:
        print(f"IMU alignment   {inertial['status']}: {inertial.get('reason', '')}")
    if "dense" in summary:
        d = summary["dense"]
        print(f"dense mesh      {d['mesh_vertices']} vertices, {d['mesh_triangles']} triangles "
              f"from {d['frames']} keyframes (fusion {d['fusion_s']:.1f} s)")
    for note in [*notes, *summary["metric_errors"]]:
        print(f"note: {note}")
    print(f"results in      {out}/ (trajectory, keyframes, maps/, map.ply, colmap/, plot.png, "
          "results.json)")


def _cmd_export(args: argparse.Namespace) -> int:
    from .colmap import TIMESTAMPS_FILE, export_map_file

    folder = export_map_file(args.map, args.colmap)
    print(f"COLMAP model in {folder}/sparse/0/; a map file holds no images: put the frames "
          f"listed in {folder}/{TIMESTAMPS_FILE} in {folder}/images/ under those names")
    return 0


def _cmd_batch(args: argparse.Namespace) -> int:
    from .batch import run_batch

    outcome = run_batch(args.spec, args.out, address=args.address,
                        cpus_per_run=args.cpus_per_run, num_cpus=args.num_cpus,
                        retry_failed=args.retry_failed, progress=not args.silent)
    failed = [row for row in outcome.rows if row["status"] != "ok"]
    for row in failed:
        print(f"ferroslam: run {row['run_dir']} {row['status']}: {row['error']}",
              file=sys.stderr)
    if not args.silent:
        print(f"{len(outcome.rows)} runs ({outcome.ran} run now, {outcome.skipped} done "
              f"before): {len(outcome.rows) - len(failed)} ok, {len(failed)} failed\n"
              f"results in {args.out}/ (results.csv, summary.md, one folder per run)")
    return 1 if failed else 0


def _cmd_merge(args: argparse.Namespace) -> int:
    from .export import write_trajectory
    from .fleet import apply_similarity, merge_chain, merge_lines, merge_maps
    from .io import read_tum_trajectory

    if not args.maps:
        raise ValueError("merge: no map files given (ferroslam merge A.map B.map ... -o OUT)")
    trajectories = []
    if args.trajectory is not None:
        if len(args.trajectory) != len(args.maps):
            raise ValueError(f"--trajectory: {len(args.trajectory)} file(s) for "
                             f"{len(args.maps)} map file(s); give one per map, in order")
        trajectories = [read_tum_trajectory(p) for p in args.trajectory]
    elif args.out_trajectories is not None:
        raise ValueError("--out-trajectories needs --trajectory (one TUM file per map)")
    result = merge_maps(args.maps, args.output)
    for line in merge_lines(result, [str(p) for p in args.maps]):
        print(line)
    print(f"{len(result['maps'])} map(s) from {len(args.maps)} file(s), "
          f"{len(result['merges'])} merge(s): {args.output}")
    if trajectories:
        folder = (args.out_trajectories if args.out_trajectories is not None
                  else args.output.parent / f"{args.output.stem}_trajectories")
        stems = [p.stem for p in args.maps]
        if len(set(stems)) < len(stems):
            stems = [f"{i}_{stem}" for i, stem in enumerate(stems)]
        for i, (traj, stem) in enumerate(zip(trajectories, stems)):
            if not result["inputs"][i]:
                print(f"{args.maps[i]}: holds no map, {args.trajectory[i]} not re-expressed")
                continue
            final, S = merge_chain(result["merges"], result["inputs"][i][-1])
            moved = apply_similarity(S, traj)
            path = write_trajectory(folder / f"{stem}.txt", moved.timestamps, moved.poses,
                                    "tum")
            print(f"{args.trajectory[i]} in the frame of map {final}: {path}")
    return 0


def _cmd_fleet(args: argparse.Namespace) -> int:
    from .fleet import run_fleet, summary_lines

    summary = run_fleet(args.spec, args.out, address=args.address, num_cpus=args.num_cpus,
                        progress=not args.silent)
    failed = [run for run in summary["runs"] if run["status"] != "ok"]
    for run in failed:
        print(f"ferroslam: run {run['run_dir']} {run['status']}: {run['error']}",
              file=sys.stderr)
    if not args.silent:
        for line in summary_lines(summary):
            print(line)
        print(f"results in {args.out}/ (summary.json, merged map files, one folder per run)")
    return 1 if failed else 0


def _cmd_eval(args: argparse.Namespace) -> int:
    from . import io, metrics

    read = io.read_tum_trajectory if args.format == "tum" else io.read_kitti_poses
    ref, est = read(args.ref), read(args.est)
    if args.metric == "ate":
        r = metrics.ate(ref, est, align=args.align, max_diff=args.max_diff)
        print(f"ATE ({args.align}, {r.pairs} pairs, scale {r.scale:.6f})")
        for k in ("rmse", "mean", "median", "std", "min", "max"):
            print(f"  {k:<6} {getattr(r, k):.6f} {r.unit}")
    else:
        r = metrics.rpe(ref, est, delta=args.delta, align=args.align, max_diff=args.max_diff)
        print(f"RPE (delta {r.delta} frames, {args.align}, {r.pairs} pairs)")
        for k in ("rmse", "mean", "median", "std", "min", "max"):
            print(f"  {k:<6} {getattr(r, f'trans_{k}'):.6f} m  "
                  f"{getattr(r, f'rot_deg_{k}'):.4f} deg")
    return 0


def _cmd_vocab(args: argparse.Namespace) -> int:
    from . import vocabulary

    if args.vocab_command == "train":
        images = vocabulary.image_paths(args.images, step=args.step)
        descriptors = vocabulary.extract_descriptors(images, n_features=args.features)
        print(f"extracted {sum(map(len, descriptors))} descriptors from {len(images)} images")
        voc = vocabulary.Vocabulary.train(descriptors, k=args.k, levels=args.levels,
                                          seed=args.seed)
        vocabulary.save_vocabulary(voc, args.out)
        print(f"wrote {args.out}: {voc!r}, {args.out.stat().st_size} bytes")
        if args.text is not None:
            vocabulary.save_vocabulary(voc, args.text, dbow2_text=True)
            print(f"wrote DBoW2 text {args.text}")
        return 0
    voc = (vocabulary.default_vocabulary() if args.vocabulary is None
           else vocabulary.Vocabulary.load(args.vocabulary))
    vocabulary.save_vocabulary(voc, args.out, dbow2_text=True)
    print(f"wrote DBoW2 text {args.out}: {voc!r}")
    return 0


def _cmd_download(args: argparse.Namespace) -> int:
    from .download import fetch_dataset, kitti_instructions

    if args.dataset == "kitti":
        print(kitti_instructions(args.name, args.to), file=sys.stderr)
        return 3
    folder = fetch_dataset(args.dataset, args.name, args.to, url=args.url, sha256=args.sha256,
                           keep_archive=args.keep_archive, progress=not args.silent,
                           timeout=args.timeout)
    sensor = "rgbd" if args.dataset == "tum" else "stereo"
    print(f"extracted to {folder}\nrun it:  ferroslam run {folder} --sensor {sensor}")
    return 0


def _one_line(err: BaseException) -> str:
    """The error as one line: its message (the type's name when the message is empty or
    says too little to stand alone, as for KeyError)."""
    text = " ".join(str(err).split())
    if isinstance(err, KeyError) or not text:
        return f"{type(err).__name__}: {text}" if text else type(err).__name__
    return text


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``ferroslam`` command; returns the exit status (0 success, 1 error,
    2 usage error, 3 ``download kitti``: manual steps needed).

    Any error is printed as one line ``ferroslam: error: ...``; ``--traceback`` or the
    environment variable ``FERROSLAM_TRACEBACK=1`` prints the stack as well."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.version:
        from . import __version__

        print(__version__)
        return 0
    if args.command is None:
        parser.print_help()
        return 2
    commands = {"run": _cmd_run, "demo": _cmd_demo, "eval": _cmd_eval,
                "download": _cmd_download, "vocab": _cmd_vocab, "batch": _cmd_batch,
                "check": _cmd_check, "export": _cmd_export, "merge": _cmd_merge,
                "fleet": _cmd_fleet}
    try:
        return commands[args.command](args)
    except KeyboardInterrupt:
        print("ferroslam: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # noqa: BLE001 - every failure of a command is one line
        if args.traceback or os.environ.get("FERROSLAM_TRACEBACK", "") not in ("", "0"):
            traceback.print_exc()
        print(f"ferroslam: error: {_one_line(err)}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
