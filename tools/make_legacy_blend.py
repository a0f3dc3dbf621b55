"""Make tests/data/legacy_4.2.blend: a .blend as the add-on made them before frame caches (issue 17), which
later versions must keep opening, rendering and copying into a frame cache (tests/test_blender_cache.py).

It holds two clips of 4 frames x 60 Gaussians on a 96 x 64 canvas: "embedded" (every frame's points in
one mesh with a `frame` attribute and the "HyperGS Frames" Geometry Nodes filter; one point of clip frame
1 deleted in Edit Mode) and "linked" (the image plane's outline, its Gaussians in legacy_linked.hgs
beside the .blend, a version 1 quantized file, stored as `//legacy_linked.hgs`).

Run with the bpy 4.2 wheel (the oldest Blender supported: every later one opens its files) and the zip of
an add-on from before frame caches (e.g. main at 77a8a53, built with tools/build_extension.py):

    .blender-matrix/bpy-4.2/bin/python tools/make_legacy_blend.py --zip OLD.zip --out tests/data
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tools")]

from blender_headless import addon_module, exit_session, install_extension, start_blender  # noqa: E402

T, N, CANVAS = 4, 60, (96, 64)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--zip", required=True, help="the add-on from before frame caches")
    parser.add_argument("--out", default=str(ROOT / "tests" / "data"))
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from hypergs_blender.gaussians import GaussianVideo
    from hypergs_blender.io.npz import save_npz

    rng = np.random.default_rng(7)
    params = np.empty((T, N, 8), np.float32)
    params[..., 0:2] = rng.uniform(-0.9, 0.9, (T, N, 2))
    params[..., 2:4] = rng.uniform(2.0, 6.0, (T, N, 2))
    params[..., 4] = rng.uniform(0, np.pi, (T, N))
    params[..., 5:8] = rng.uniform(0.05, 0.3, (T, N, 3))
    video = GaussianVideo(params, *CANVAS, fps=24.0, source=dict(path="legacy.mp4", frames=list(range(T))))
    work = Path(tempfile.mkdtemp(prefix="hypergs-legacy-"))
    save_npz(video, work / "legacy.npz")

    bpy = start_blender(work / "user")
    addon = install_extension(bpy, args.zip)
    hgs = addon_module(addon, "hypergs_blender.io.hgs")  # the add-on's own codec (its bundled wheels)
    hgs.save_hgs(hgs.GaussianVideo(params, *CANVAS, fps=24.0), out / "legacy_linked.hgs")
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1 backup
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = CANVAS
    scene.render.fps = 24
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "legacy_4.2.blend"))  # saved first: the link is stored relative
    bpy.ops.hypergs.import_clip(filepath=str(work / "legacy.npz"))
    embedded = bpy.context.view_layer.objects.active
    embedded.name = embedded.data.name = "embedded"
    import bmesh
    frame = np.empty(len(embedded.data.vertices), np.int32)
    embedded.data.attributes["frame"].data.foreach_get("value", frame)
    bpy.ops.object.mode_set(mode="EDIT")
    bm = bmesh.from_edit_mesh(embedded.data)
    bm.verts.ensure_lookup_table()
    bm.verts.remove(bm.verts[int(np.flatnonzero(frame == 1)[10])])
    bmesh.update_edit_mesh(embedded.data)
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.hypergs.import_clip(filepath=str(out / "legacy_linked.hgs"), link=True)
    linked = bpy.context.view_layer.objects.active
    linked.name = linked.data.name = "linked"
    bpy.context.preferences.filepaths.use_file_compression = True
    bpy.ops.wm.save_mainfile(compress=True)
    print(f"{out / 'legacy_4.2.blend'}: {(out / 'legacy_4.2.blend').stat().st_size / 1e3:.0f} kB, "
          f"Blender {bpy.app.version_string}; linked path {linked.hypergs.linked_path}")
    return 0


if __name__ == "__main__":
    exit_session(main())
