"""The one declaration of every option, and the one check every entry point runs.

Each option is declared once (:data:`OPTIONS`) with its type, range, unit, the sensors it
applies to and whether it needs an IMU. The same declaration serves the Python keywords of
``Session``, the vSLAM objects and ``run_sequence``, the ``--config`` keys of ``ferroslam
run`` and the ``options`` of a batch SPEC; MATLAB-style keyword names (``max_num_points``,
``num_levels``) are aliases of the core names.

The options the core takes (scopes ``"core"``, ``SlamSystem`` keywords, and ``"imu"``,
``SlamSystem.set_imu`` keywords: inertial sensors only) are not declared here: they are read
at import from the core's table (``ferroslam._core.option_table()``, built from the core's
configuration in ``crates/slam/src/config/options.rs``) with their types, ranges, units,
sensors, docs and defaults; this module adds only what is Python's, the MATLAB aliases. The
other scopes are Python's own: ``"pipeline"`` (``run_sequence`` / ``--config`` / SPEC only),
``"source"`` (how the input is read: ``ferroslam run`` flags, ``open_sequence`` /
``open_bag`` keywords), ``"object"`` (keywords of the vSLAM objects) and ``"attribute"``
(attributes of the vSLAM objects, checked with :func:`check_option`). Options left out take
the core's defaults (``ferroslam._core.default_options``) or, for the pipeline's, the
declared ``default``. ``docs/options.md`` is generated from :data:`OPTIONS`
(``scripts/options_doc.py``).
"""

from __future__ import annotations

import json
import math
import numbers
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from ._files import MAX_CONFIG_BYTES, check_nesting, read_bounded_text
from .dense import DEFAULT_MAX_DEPTH_M, DEFAULT_TRUNCATION_M, DEFAULT_VOXEL_M

__all__ = ["EXTRACTOR_KEYS", "IMU_KEYS", "OPTIONS", "Option", "check_option", "core_default",
           "load_option_file", "pipeline_default", "validate_options"]

SENSORS = ("mono", "stereo", "rgbd")
_INERTIAL = "-inertial"
_ALL = SENSORS
# What a run can be asked to track (run_sequence, the command line, bags, batch SPECs): the
# core's sensors and a camera rig (tracked as one of them), each with or without an IMU.
RUN_SENSORS = (*SENSORS, "rig", *(f"{s}{_INERTIAL}" for s in (*SENSORS, "rig")))


@dataclass(frozen=True)
class Option:
    """One option: ``kind`` is ``"int"``, ``"float"``, ``"flag"``, ``"int_pair"``,
    ``"float_pair"`` or ``"vocabulary"``; values must lie in ``low..high`` (``None``: no
    bound; ``open_low``/``open_high`` exclude the bound); a pair's elements each lie there
    and increase; ``unit`` is for messages; ``sensors`` the camera sensors it applies to;
    ``inertial`` true for options that need an IMU."""

    name: str
    kind: str
    scope: str
    unit: str = ""
    low: Optional[float] = None
    high: Optional[float] = None
    open_low: bool = False
    open_high: bool = False
    sensors: tuple[str, ...] = _ALL
    inertial: bool = False
    aliases: tuple[str, ...] = ()
    matlab: str = ""
    infinite_high: bool = False  # a float (or a pair's upper value) may be +inf
    # The default of an option the core does not take (scope "pipeline"); core options
    # take the core's (``defaults``, per sensor).
    default: Any = None
    doc: str = ""
    # The configuration field a core option sets (``section.field``; ``imu.field``).
    field: Optional[str] = None
    # A core option's default per camera sensor for images 640 px wide (the core's
    # ``option_table``); ``None`` where it has none (``baseline``).
    defaults: Optional[dict[str, Any]] = None

    def range_text(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if self.low is not None and self.high is not None:
            lo, hi = ("(" if self.open_low else "["), (")" if self.open_high else "]")
            return f"in {lo}{_num(self.low)}, {_num(self.high)}{hi}{unit}"
        if self.low is not None:
            return f"{'>' if self.open_low else '>='} {_num(self.low)}{unit}"
        if self.high is not None:
            return f"{'<' if self.open_high else '<='} {_num(self.high)}{unit}"
        return f"any{unit}"


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(x)


# What only Python adds to the core's options: MATLAB-style keyword aliases and the names of
# MATLAB's properties (for the vSLAM objects' docs).
_MATLAB = {
    "n_features": (("max_num_points",), "MaxNumPoints"),
    "scale_factor": ((), "ScaleFactor"),
    "n_levels": (("num_levels",), "NumLevels"),
    "track_feature_range": ((), "TrackFeatureRange"),
    "skip_max_frames": ((), "SkipMaxFrames"),
    "loop_closure_threshold": ((), "LoopClosureThreshold"),
    "num_poses_threshold": ((), "NumPosesThreshold"),
    "alignment_fraction": ((), "AlignmentFraction"),
}


def _core_options() -> tuple[Option, ...]:
    """The core's options (``_core.option_table()``) as :class:`Option` s; none without the
    native module (then only the Python scopes are checked)."""
    try:
        from ._core import option_table
    except ImportError:
        return ()
    options = []
    for entry in option_table():
        aliases, matlab = _MATLAB.get(entry["name"], ((), ""))
        options.append(Option(
            entry["name"], entry["kind"], entry["scope"], entry["unit"], entry["low"],
            entry["high"], entry["open_low"], entry["open_high"], tuple(entry["sensors"]),
            inertial=entry["scope"] == "imu", aliases=aliases, matlab=matlab,
            infinite_high=entry["infinite_high"], doc=entry["doc"], field=entry["field"],
            defaults={k: tuple(v) if isinstance(v, list) else v
                      for k, v in entry["defaults"].items()}))
    return tuple(options)


OPTIONS: tuple[Option, ...] = _core_options() + (
    # -- run_sequence / --config / SPEC --------------------------------------------------
    Option("vocabulary", "vocabulary", "pipeline", default="default",
           doc="Bag of words for relocalisation and loops: \"default\" (shipped), a file, "
               "a Vocabulary or None"),
    Option("mapping_thread", "flag", "pipeline", default=False,
           doc="Local mapping and loop closing in their own thread"),
    Option("dense", "flag", "pipeline", sensors=("rgbd",), default=False,
           doc="TSDF fusion of the RGB-D keyframes into mesh.ply (ferroslam.dense; run "
               "--dense)"),
    Option("dense_voxel_m", "float", "pipeline", "metres", 0, None, open_low=True,
           sensors=("rgbd",), default=DEFAULT_VOXEL_M, doc="Voxel size of the fusion"),
    Option("dense_truncation_m", "float", "pipeline", "metres", 0, None, open_low=True,
           sensors=("rgbd",), default=DEFAULT_TRUNCATION_M,
           doc="Truncation distance of the signed distance field, above dense_voxel_m"),
    Option("dense_max_depth_m", "float", "pipeline", "metres", 0, None, open_low=True,
           sensors=("rgbd",), default=DEFAULT_MAX_DEPTH_M,
           doc="Depths beyond this are left out of the fusion"),
    # -- the input (ferroslam run flags, open_sequence / open_bag keywords) ---------------
    Option("depth_scale", "float", "source", "depth pixel values per metre", 0, None,
           open_low=True, sensors=("rgbd",),
           doc="Depth image value of one metre (TUM 5000); default the layout's"),
    Option("pair_tolerance_s", "float", "source", "s", 0, 1, open_low=True,
           sensors=("stereo", "rgbd"),
           doc="Largest time between the two images of a pair (colour and depth, left and "
               "right)"),
    # -- vSLAM objects -------------------------------------------------------------------
    Option("threaded", "flag", "object",
           doc="Track in a background thread (add_frame returns at once)"),
    Option("localization_only", "flag", "attribute",
           doc="Track against the map without changing it"),
)

_BY_NAME = {o.name: o for o in OPTIONS}
# The set_imu keywords, and the options of the ORB extractor (``OrbExtractor`` keywords), in
# the core's order: the key lists of ``session.py`` and ``pipeline.py``.
IMU_KEYS = tuple(o.name for o in OPTIONS if o.scope == "imu")
EXTRACTOR_KEYS = tuple(o.name for o in OPTIONS if (o.field or "").startswith("extractor."))
_BY_ALIAS = {a: o for o in OPTIONS for a in o.aliases}
# Who takes which scopes, for messages.
_SCOPE_USERS = {
    "core": "every entry point",
    "imu": "every entry point (inertial sensors)",
    "pipeline": "run_sequence, --config and batch SPEC options",
    "object": "the vSLAM objects (MonoVSlam, StereoVSlam, RGBDVSlam) as keywords",
    "attribute": "the vSLAM objects as an attribute (vslam.localization_only = True)",
    "source": "the input: ferroslam run's flags (--depth-scale), open_sequence and open_bag "
              "keywords",
}
# The scopes a configuration (run_sequence config, --config file, SPEC options) may hold.
CONFIG_SCOPES = ("core", "imu", "pipeline")


def _split_sensor(sensor: str, inertial: bool) -> tuple[str, bool]:
    if not isinstance(sensor, str):
        raise TypeError(f"sensor must be a string, got {sensor!r}")
    camera = sensor[: -len(_INERTIAL)] if sensor.endswith(_INERTIAL) else sensor
    if camera not in SENSORS:
        raise ValueError(f"unknown sensor {sensor!r}; expected one of {SENSORS} (optionally "
                         f"with {_INERTIAL})")
    return camera, bool(inertial) or camera != sensor


def validate_options(options: Optional[dict], sensor: str, inertial: bool = False, *,
                     scopes: tuple[str, ...] = CONFIG_SCOPES) -> dict:
    """``options`` checked against :data:`OPTIONS` for ``sensor`` (``"mono"``, ``"stereo"``,
    ``"rgbd"``, or with ``-inertial``, which sets ``inertial``) and normalised: canonical
    names (aliases resolved), bools, ints, floats, pairs as tuples. Options left out stay
    out (the core's defaults apply).

    Raises:
        TypeError: a name that is not a string; a value of the wrong type (a flag that is not
            a bool: ``"no"`` or ``1`` is refused), naming the option.
        ValueError: an unknown option, one given twice (as an alias too), one that does not
            apply to ``sensor`` or needs an IMU, one of a scope not in ``scopes``, or a value
            out of range or not finite, naming the option, the value, the range and unit.
    """
    camera, inertial = _split_sensor(sensor, inertial)
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError(f"options must be a dict of option names to values, got "
                        f"{type(options).__name__}")
    out: dict[str, Any] = {}
    given_as: dict[str, str] = {}
    for key, value in options.items():
        if not isinstance(key, str):
            raise TypeError(f"option names must be strings, got {key!r}")
        option = _BY_NAME.get(key) or _BY_ALIAS.get(key)
        if option is None:
            known = ", ".join(sorted(o.name for o in OPTIONS if o.scope in scopes))
            raise ValueError(f"unknown option {key!r} (known: {known})")
        if option.scope not in scopes:
            raise ValueError(f"option {key!r} is taken by {_SCOPE_USERS[option.scope]}, not "
                             "here")
        if option.name in given_as:
            raise ValueError(f"option {key!r} given twice (also as {given_as[option.name]!r})")
        if camera not in option.sensors:
            raise ValueError(f"option {key!r} applies to sensor {' or '.join(option.sensors)}, "
                             f"not {sensor!r}")
        if option.inertial and not inertial:
            raise ValueError(f"option {key!r} is an IMU option: it applies to the -inertial "
                             f"sensors, and sensor {sensor!r} has no IMU")
        given_as[option.name] = key
        out[option.name] = _check_value(option, key, value)
    _check_together(out)
    return out


def core_default(name: str, sensor: str) -> Any:
    """The core's default of option ``name`` for camera sensor ``sensor`` (images 640 px
    wide; the core's table)."""
    return _BY_NAME[name].defaults[sensor]


def pipeline_default(options: dict, name: str) -> Any:
    """``options[name]``, or the declared default of that pipeline option."""
    return options.get(name, _BY_NAME[name].default)


def check_option(name: str, value: Any) -> Any:
    """One option's value checked and normalised (attribute setters such as
    ``localization_only``); raises as :func:`validate_options`."""
    option = _BY_NAME.get(name) or _BY_ALIAS[name]
    return _check_value(option, name, value)


def _check_value(option: Option, key: str, value: Any) -> Any:
    if option.kind == "flag":
        if not isinstance(value, (bool, np.bool_)):
            raise TypeError(f"option {key!r}: expected True or False, got {value!r}")
        return bool(value)
    if option.kind == "vocabulary":
        if value is None or isinstance(value, (bool, str, os.PathLike)) or hasattr(
                value, "transform"):
            return value
        raise TypeError(f"option {key!r}: expected \"default\", a vocabulary file, a "
                        f"Vocabulary or None, got {type(value).__name__}")
    if option.kind in ("int_pair", "float_pair"):
        element = "int" if option.kind == "int_pair" else "float"
        if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") \
                or len(value) != 2:
            raise TypeError(f"option {key!r}: expected a pair (lower, upper) of "
                            f"{element}s, got {value!r}")
        low, high = (_scalar(option, element, key, v, i == 1) for i, v in enumerate(value))
        if not low < high:
            raise ValueError(f"option {key!r} = {tuple(value)!r}: lower must be below upper")
        return (low, high)
    return _scalar(option, option.kind, key, value, True)


def _scalar(option: Option, kind: str, key: str, value: Any, may_be_inf: bool):
    unit = f" of {option.unit}" if option.unit else ""
    if isinstance(value, (bool, np.bool_)) or not isinstance(
            value, numbers.Integral if kind == "int" else numbers.Real):
        what = "an integer" if kind == "int" else "a number"
        raise TypeError(f"option {key!r}: expected {what}{unit}, got {value!r}")
    number = int(value) if kind == "int" else float(value)
    if kind == "float" and not math.isfinite(number) and not (
            option.infinite_high and may_be_inf and number == math.inf):
        raise ValueError(f"option {key!r} = {value!r}: must be a finite number{unit}")
    low_bad = option.low is not None and (number <= option.low if option.open_low
                                          else number < option.low)
    high_bad = option.high is not None and (number >= option.high if option.open_high
                                            else number > option.high)
    if low_bad or high_bad:
        raise ValueError(f"option {key!r} = {value!r}: must be {option.range_text()}")
    return number


def _check_together(options: dict) -> None:
    voxel_m = pipeline_default(options, "dense_voxel_m")
    truncation_m = pipeline_default(options, "dense_truncation_m")
    if ("dense_voxel_m" in options or "dense_truncation_m" in options) \
            and not voxel_m < truncation_m:
        raise ValueError(f"option 'dense_truncation_m' = {truncation_m} must exceed "
                         f"'dense_voxel_m' = {voxel_m}: the distance field spans voxels")
    if "min_fast" in options and "ini_fast" in options \
            and options["min_fast"] > options["ini_fast"]:
        raise ValueError(f"option 'min_fast' = {options['min_fast']} must be at most "
                         f"'ini_fast' = {options['ini_fast']}")


# -- option files ---------------------------------------------------------------------------

# Options are flat (a pair is depth 2); SPECs nest a few levels more.
MAX_OPTION_FILE_DEPTH = 16


def load_option_file(path: Union[str, os.PathLike], max_bytes: int = MAX_CONFIG_BYTES,
                     max_depth: int = MAX_OPTION_FILE_DEPTH) -> dict:
    """The mapping of a JSON (``.json``) or YAML (any other name) options file, bounded:
    its size is checked before it is read and its nesting depth before parsing (brackets)
    and after it (YAML block style): a deeply nested file is refused, never a
    ``RecursionError``. Reads through the package's one bounded reader
    (``_files.read_bounded_text``).

    Raises:
        FileNotFoundError: no such file. IsADirectoryError: a folder.
        ValueError: naming the file: not a regular file (a FIFO or device is refused before
            it is opened, so nothing blocks), larger than ``max_bytes``, not UTF-8, invalid
            JSON/YAML, nested deeper than ``max_depth``, not a mapping with string keys.
    """
    path = Path(path)
    text = read_bounded_text(path, max_bytes, "options file")
    check_nesting(text, str(path), max_depth)
    document = _parse(path, text)
    if _depth(document) > max_depth:
        raise ValueError(f"{path}: nested deeper than {max_depth} levels")
    if not isinstance(document, dict) or not all(isinstance(k, str) for k in document):
        raise ValueError(f"{path}: an options file must hold a JSON object (a mapping) of "
                         f"option names to values, got {type(document).__name__}")
    return document


def _parse(path: Path, text: str) -> Any:
    try:
        if path.suffix.lower() == ".json":
            try:
                return json.loads(text)
            except json.JSONDecodeError as err:
                raise ValueError(f"{path}: invalid JSON: {err}") from None
        import yaml

        try:
            return yaml.safe_load(text)
        except yaml.YAMLError as err:
            raise ValueError(f"{path}: invalid YAML: {err}") from None
    except RecursionError:  # check_nesting bounds flow nesting; this is the last guard
        raise ValueError(f"{path}: nested too deep to parse") from None


def _depth(value: Any) -> int:
    """Nesting depth of parsed containers, iteratively, each shared (YAML alias) container
    counted once."""
    deepest = 0
    seen: set[int] = set()
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if not isinstance(item, (dict, list)) or id(item) in seen:
            continue
        seen.add(id(item))
        deepest = max(deepest, depth)
        stack.extend((child, depth + 1)
                     for child in (item.values() if isinstance(item, dict) else item))
    return deepest
