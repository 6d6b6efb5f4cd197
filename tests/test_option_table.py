"""The core's option table is the one source of every option's type, range and default: the
Python declarations, ``default_options``, ``set_imu``'s signature, the stub and
docs/options.md all agree with it."""

from __future__ import annotations

import ast
import importlib.util
import inspect
import re
from pathlib import Path

import numpy as np
import pytest

from ferroslam import pipeline, session
from ferroslam._core import SlamSystem, default_options, option_table
from ferroslam.options import EXTRACTOR_KEYS, IMU_KEYS, OPTIONS, validate_options

ROOT = Path(__file__).resolve().parents[1]
STUB = ROOT / "python" / "ferroslam" / "_core.pyi"
SENSORS = ("mono", "stereo", "rgbd")
# The stub's annotation of each kind of option.
STUB_TYPES = {"int": "int", "float": "float", "flag": "bool", "int_pair": "Sequence[int]",
              "float_pair": "Sequence[float]"}


def _core_names() -> list[str]:
    """The names the binding parses, in its order, from its error for an unknown one."""
    with pytest.raises(ValueError, match="unknown option") as err:
        SlamSystem(500.0, 500.0, 320.0, 240.0, np.zeros(5), 640, 480, sensor="mono",
                   no_such_option=1)
    return re.search(r"known: (.*)$", str(err.value)).group(1).split(", ")


def test_python_declarations_are_the_core_table_in_order():
    table = option_table()
    declared = [o for o in OPTIONS if o.scope in ("core", "imu")]
    assert [(o.name, o.scope, o.kind, o.unit, o.sensors) for o in declared] == [
        (e["name"], e["scope"], e["kind"], e["unit"], e["sensors"]) for e in table]
    # The binding parses exactly the core-scope options, in the table's order.
    assert _core_names() == [e["name"] for e in table if e["scope"] == "core"]
    assert IMU_KEYS == ("num_poses_threshold", "alignment_fraction", "gravity_magnitude",
                        "imu_time_offset_s")


@pytest.mark.parametrize("width, n_features", [(640, 1000), (752, 1200), (1241, 1900)])
def test_table_defaults_are_default_options(width, n_features):
    table = option_table(width)
    for sensor in SENSORS:
        core = {e["name"]: e["defaults"][sensor] for e in table
                if e["scope"] == "core" and e["name"] != "baseline"}
        assert default_options(sensor, width) == core
        assert core["n_features"] == n_features
    baseline = next(e for e in table if e["name"] == "baseline")
    assert baseline["defaults"] == {"mono": None, "stereo": None, "rgbd": None}


def test_imu_defaults_are_set_imu_defaults():
    imu = {e["name"]: e["defaults"]["mono"] for e in option_table() if e["scope"] == "imu"}
    assert imu == {"num_poses_threshold": 20, "alignment_fraction": 0.9,
                   "gravity_magnitude": 9.81, "imu_time_offset_s": 0.0}
    # set_imu restates none of them: an option left out (None) takes the core's default.
    signature = inspect.signature(SlamSystem.set_imu)
    assert {k: p.default for k, p in signature.parameters.items()
            if p.kind is p.KEYWORD_ONLY} == dict.fromkeys(imu)


def test_ranges_come_from_the_core():
    by_name = {o.name: o for o in OPTIONS}
    assert by_name["gravity_magnitude"].range_text() == "in [9.7, 9.9] m/s^2"
    assert by_name["imu_time_offset_s"].range_text() == "in [-1, 1] s"
    assert by_name["loop_closure_threshold"].range_text() == "in [20, 4294967295] points"
    assert by_name["seed"].high == 2**64 - 1  # exact, not the float 2^64
    with pytest.raises(ValueError, match=rf"option 'seed' = {2**64}: must be in \[0, "
                                         rf"{2**64 - 1}\]"):
        validate_options({"seed": 2**64}, "mono")
    with pytest.raises(ValueError, match="width = 0: image width must be positive"):
        option_table(0)


def test_the_core_refuses_what_the_table_refuses():
    """The core's own checks (set_imu) use the ranges the table declares."""
    slam = SlamSystem(500.0, 500.0, 320.0, 240.0, np.zeros(5), 640, 480, sensor="mono")
    imu = dict(gyroscope_noise_density=1.7e-4, gyroscope_random_walk=1.9e-5,
               accelerometer_noise_density=2.0e-3, accelerometer_random_walk=3.0e-3,
               rate_hz=200.0)
    with pytest.raises(ValueError, match=r"imu: gravity_magnitude = 1 must be in \[9.7, 9.9\] "
                                         "m/s\\^2"):
        slam.set_imu(imu, np.eye(4), gravity_magnitude=1.0)
    with pytest.raises(ValueError, match=r"imu: imu_time_offset_s = 2 must be in \[-1, 1\] s"):
        slam.set_imu(imu, np.eye(4), imu_time_offset_s=2.0)
    slam.set_imu(imu, np.eye(4), gravity_magnitude=9.9, imu_time_offset_s=-1.0)


def test_session_and_pipeline_key_lists_are_the_derived_ones():
    # session.py / pipeline.py keep their own lists until they import these (options.py
    # derives them from the table): they must agree.
    assert session.IMU_KEYS == IMU_KEYS
    # Only membership matters there (the extractor's keywords are passed by name).
    assert set(session.EXTRACTOR_KEYS) == set(pipeline.EXTRACTOR_KEYS) == set(EXTRACTOR_KEYS)


def _stub_class(tree: ast.Module, name: str) -> ast.ClassDef:
    return next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name)


def test_stub_options_agree_with_the_table():
    tree = ast.parse(STUB.read_text(encoding="utf-8"))
    fields = {}
    docs = {}
    body = _stub_class(tree, "_SlamOptions").body
    for node, after in zip(body, body[1:] + [None]):
        if isinstance(node, ast.AnnAssign):
            fields[node.target.id] = ast.unparse(node.annotation)
            if isinstance(after, ast.Expr):
                docs[node.target.id] = after.value.value
    core = [e for e in option_table() if e["scope"] == "core"]
    assert fields == {e["name"]: STUB_TYPES[e["kind"]] for e in core}
    # The defaults and ranges are the table's: the stub's docs do not restate them.
    for name, doc in docs.items():
        assert not re.search(r"default \(?[\d(]|default (True|False)|[<>]=? ?\d", doc), name
    set_imu = next(n for n in _stub_class(tree, "SlamSystem").body
                   if isinstance(n, ast.FunctionDef) and n.name == "set_imu")
    stub_imu = {a.arg: ast.literal_eval(d)
                for a, d in zip(set_imu.args.kwonlyargs, set_imu.args.kw_defaults)}
    assert stub_imu == dict.fromkeys(e["name"] for e in option_table() if e["scope"] == "imu")


def test_options_doc_is_generated_from_the_table():
    spec = importlib.util.spec_from_file_location("options_doc",
                                                  ROOT / "scripts" / "options_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    text = (ROOT / "docs" / "options.md").read_text(encoding="utf-8")
    assert text == module.render(), "docs/options.md is stale: python scripts/options_doc.py"
    for entry in option_table():
        assert f"`{entry['name']}`" in text
    assert "| `gravity_magnitude` | float | 9.81 | in [9.7, 9.9] m/s^2 |" in text
