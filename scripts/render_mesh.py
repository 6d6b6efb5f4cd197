"""Renders the TSDF mesh of a `ferroslam run --dense` to a PNG, headless and on the CPU: the
README's picture (docs/images/tum_rpy_mesh.png).

    python scripts/render_mesh.py                       # runs fr1/rpy RGB-D, 300 frames
    python scripts/render_mesh.py --mesh out/mesh.ply   # a mesh already written

Open3D's OffscreenRenderer needs an EGL or Vulkan driver, which a CPU-only machine without a
display lacks ("Failed to load vulkan library!"), so the mesh is drawn with matplotlib: the
triangles projected through a pinhole placed behind the first keyframe (the world frame of a
run), painted far to near (painter's algorithm), each in its vertices' mean colour times a
Lambert term from a head light, so that the shape reads beside the texture.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = Path(os.environ.get("FERROSLAM_DATA", REPO.parent / "shared" / "data"))
DEFAULT_OUT = REPO / "docs" / "images" / "tum_rpy_mesh.png"
# A readable picture within the README's size budget (< 300 KB as a 256-colour PNG).
WIDTH_PX, HEIGHT_PX = 900, 640
FOCAL_PX = 480.0
# Behind and above the first camera, so the whole desk the rpy motion swept is in view.
EYE_OFFSET_C_M = np.array([0.3, -0.6, -1.2])
# Meshes of a few 10^5 triangles take seconds to draw; decimated beyond that.
MAX_TRIANGLES = 300_000


def run_dense(sequence: Path, out: Path) -> Path:
    """``ferroslam run SEQUENCE --sensor rgbd --dense`` into ``out``; the mesh it wrote."""
    from ferroslam.cli import main

    if main(["run", str(sequence), "--sensor", "rgbd", "--dense", "--silent",
             "--out", str(out)]) != 0:
        raise SystemExit(f"ferroslam run failed on {sequence}")
    return out / "mesh.ply"


def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (V, 3) m, triangles (T, 3) and vertex colours (V, 3) in [0, 1]."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    if len(mesh.triangles) > MAX_TRIANGLES:
        mesh = mesh.simplify_quadric_decimation(MAX_TRIANGLES)
    return (np.asarray(mesh.vertices), np.asarray(mesh.triangles),
            np.asarray(mesh.vertex_colors))


def render(vertices: np.ndarray, triangles: np.ndarray, colors: np.ndarray, path: Path) -> None:
    """Draws the mesh seen from ``EYE_OFFSET_C_M`` in the world (first camera) frame, looking
    at the mesh's median point, into ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from PIL import Image

    target = np.median(vertices, axis=0)
    eye = EYE_OFFSET_C_M
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross([0.0, 1.0, 0.0], z)  # the world's y points down, as a camera's does
    x /= np.linalg.norm(x)
    R_c_w = np.stack([x, np.cross(z, x), z])
    p_c = (vertices - eye) @ R_c_w.T
    corners = p_c[triangles]  # (T, 3, 3)
    ahead = (corners[:, :, 2] > 0.05).all(axis=1)
    corners, faces = corners[ahead], triangles[ahead]
    uv = FOCAL_PX * corners[:, :, :2] / corners[:, :, 2:] + [WIDTH_PX / 2, HEIGHT_PX / 2]

    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    view = corners.mean(axis=1)
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    lambert = np.abs((normals * view).sum(axis=1))
    shade = colors[faces].mean(axis=1) * (0.6 + 0.4 * lambert)[:, None]

    order = np.argsort(-corners[:, :, 2].mean(axis=1))  # far first
    dpi = 100
    fig = plt.figure(figsize=(WIDTH_PX / dpi, HEIGHT_PX / dpi), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.add_collection(PolyCollection(uv[order], facecolors=np.clip(shade[order], 0, 1),
                                     edgecolors="none", antialiased=False))
    ax.set_xlim(0, WIDTH_PX)
    ax.set_ylim(HEIGHT_PX, 0)
    ax.set_axis_off()
    fig.patch.set_facecolor("white")
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        full = Path(tmp) / "full.png"
        fig.savefig(full, dpi=dpi, facecolor="white")
        plt.close(fig)
        Image.open(full).convert("RGB").quantize(256).save(path, optimize=True)
    print(f"{path}: {len(faces)} triangles drawn of {len(triangles)}, "
          f"{path.stat().st_size / 1024:.0f} KB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", type=Path, help="a mesh.ply written by `ferroslam run --dense`"
                        " (default: run TUM fr1/rpy RGB-D, 300 frames, to write one)")
    parser.add_argument("--sequence", type=Path,
                        default=DEFAULT_DATA / "tum" / "rgbd_dataset_freiburg1_rpy")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        mesh = args.mesh or run_dense(args.sequence, Path(tmp) / "run")
        render(*load_mesh(mesh), args.out)


if __name__ == "__main__":
    main()
