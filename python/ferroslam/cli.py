"""Command line: ``ferroslam run`` (track a sequence) and ``ferroslam eval ate|rpe``.

``build_parser()`` is separate from ``main()`` so the parser is testable without a process.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Optional, Sequence

from .metrics import ALIGNMENTS
from .pipeline import SENSORS

__all__ = ["build_parser", "main"]


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def _add_eval_inputs(p: argparse.ArgumentParser, default_align: str) -> None:
    p.add_argument("ref", type=Path, help="reference (ground-truth) trajectory file")
    p.add_argument("est", type=Path, help="estimated trajectory file")
    p.add_argument("--format", choices=("tum", "kitti"), default="tum",
                   help="file format of both files (default: tum)")
    p.add_argument("--align", choices=ALIGNMENTS, default=default_align,
                   help=f"alignment of the estimate (default: {default_align})")
    p.add_argument("--max-diff", type=float, default=0.01,
                   help="timestamp association tolerance in seconds (default: 0.01)")


def build_parser() -> argparse.ArgumentParser:
    """The ``ferroslam`` argument parser (subcommands ``run`` and ``eval {ate,rpe}``)."""
    parser = argparse.ArgumentParser(
        prog="ferroslam", description="Visual SLAM (ORB-SLAM pipeline) with a Rust core."
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    run = sub.add_parser("run", help="track a dataset sequence and evaluate it")
    run.add_argument("path", type=Path,
                     help="sequence folder: TUM RGB-D, KITTI odometry or EuRoC (ASL) layout")
    algo = run.add_argument_group("algorithm")
    algo.add_argument("--sensor", choices=SENSORS, required=True, help="camera setup")
    algo.add_argument("--format", choices=("auto", "tum", "kitti", "euroc"), default="auto",
                      help="dataset layout (default: detect)")
    algo.add_argument("--config", type=Path, help="JSON file of SlamSystem/extractor options")
    algo.add_argument("--seed", type=int, help="random seed (overrides the config's 'seed')")
    algo.add_argument("--max-frames", type=_positive_int, help="process only the first N frames")
    output = run.add_argument_group("output")
    output.add_argument("--out", type=Path,
                        help="output folder (default: out/<sequence name>)")
    output.add_argument("--silent", action="store_true", help="no progress bar, no summary")

    ev = sub.add_parser("eval", help="evaluate trajectory files")
    ev_sub = ev.add_subparsers(dest="metric", metavar="METRIC", required=True)
    ate_p = ev_sub.add_parser("ate", help="absolute trajectory error (translation, metres)")
    _add_eval_inputs(ate_p, "se3")
    rpe_p = ev_sub.add_parser("rpe", help="relative pose error over --delta frames")
    _add_eval_inputs(rpe_p, "none")
    rpe_p.add_argument("--delta", type=_positive_int, default=1, help="frames (default: 1)")
    _add_vocab_parser(sub)
    return parser


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


def _load_config(path: Optional[Path]) -> dict:
    if path is None:
        return {}
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: invalid JSON: {err}") from None
    if not isinstance(config, dict):
        raise ValueError(f"{path}: the config must be a JSON object of options")
    if "track_feature_range" in config:  # JSON has no tuples
        config["track_feature_range"] = tuple(config["track_feature_range"])
    return config


def _cmd_run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    from .datasets import open_sequence
    from .io import write_tum_trajectory
    from .pipeline import run_sequence
    from .plot import plot_trajectory_top_view

    config = _load_config(args.config)
    if args.seed is not None:
        config["seed"] = args.seed
    seq = open_sequence(args.path, args.format)
    out = args.out if args.out is not None else Path("out") / seq.name
    out.mkdir(parents=True, exist_ok=True)
    result = run_sequence(seq, config, max_frames=args.max_frames, progress=not args.silent,
                          sensor=args.sensor)

    write_tum_trajectory(out / "trajectory.txt", result.trajectory.timestamps,
                         result.trajectory.poses)
    write_tum_trajectory(out / "keyframes.txt", result.keyframes.timestamps,
                         result.keyframes.poses)
    if result.ate_frames is not None:
        plot_trajectory_top_view(result.ate_frames.aligned, result.ate_frames.reference,
                                 out / "trajectory_top.png",
                                 title=f"{seq.name} (SE(3)-aligned to ground truth)")
    else:
        plot_trajectory_top_view(result.trajectory, None, out / "trajectory_top.png",
                                 title=seq.name)
    summary = result.summary()
    (out / "results.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    if not args.silent:
        _print_summary(summary, out)
    return 0


def _print_summary(summary: dict, out: Path) -> None:
    print(f"sequence        {summary['sequence']}  ({summary['sensor']})")
    print(f"tracked frames  {summary['tracked_frames']}/{summary['frames']}  "
          f"keyframes {summary['keyframes']}  map points {summary['map_points']}")
    frame = summary["timing_ms"].get("frame_ms")
    if frame:
        print(f"time per frame  median {frame['median']:.1f} ms  p95 {frame['p95']:.1f} ms")
    metrics = summary["metrics"]
    if summary["first_initialised_frame"] is None:
        print("status          not initialised: the map never started")
    elif summary["sensor"] == "mono":
        print(f"initialised at  frame {summary['first_initialised_frame']}; "
              f"{100 * summary['tracked_after_init']:.1f} % of the later frames tracked, "
              f"{summary['segments']} map segment(s)")
    for name, label in (("ate_frames", "ATE frames"), ("ate_keyframes", "ATE keyframes")):
        if name in metrics:
            m = metrics[name]
            align = "Sim(3), longest segment" if m["align"] == "sim3" else "SE(3)"
            print(f"{label:<15} RMSE {m['rmse']:.4f} m  ({align}, {m['pairs']} poses)")
    if "path_length" in metrics:
        p = metrics["path_length"]
        print(f"path length     {p['estimate_m']:.3f} m vs {p['reference_m']:.3f} m "
              f"(scale error {100 * p['scale_error']:+.2f} %)")
    if "rpe_frames" in metrics:
        r = metrics["rpe_frames"]
        print(f"RPE (1 frame)   {r['trans_rmse_m']:.4f} m  {r['rot_rmse_deg']:.3f} deg RMSE")
    for err in summary["metric_errors"]:
        print(f"note: {err}")
    print(f"results in      {out}")


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
        voc.save(args.out)
        print(f"wrote {args.out}: {voc!r}, {args.out.stat().st_size} bytes")
        if args.text is not None:
            voc.save_dbow2_text(args.text)
            print(f"wrote DBoW2 text {args.text}")
        return 0
    voc = (vocabulary.default_vocabulary() if args.vocabulary is None
           else vocabulary.Vocabulary.load(args.vocabulary))
    voc.save_dbow2_text(args.out)
    print(f"wrote DBoW2 text {args.out}: {voc!r}")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``ferroslam`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.version:
        from . import __version__

        print(__version__)
        return 0
    if args.command is None:
        parser.print_help()
        return 2
    try:
        if args.command == "run":
            return _cmd_run(args, parser)
        if args.command == "vocab":
            return _cmd_vocab(args)
        return _cmd_eval(args)
    except (FileNotFoundError, ImportError, ValueError, NotImplementedError) as err:
        print(f"ferroslam: error: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
