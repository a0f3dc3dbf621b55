"""The held-out 720p evaluation set: 2-second 1280x720 pans (48 frames, 24 fps) over the 4 held-out
wallpaper photos, which training never sees (`hypergs prepare-data` downloads them into data/).

    .venv/bin/python tools/make_heldout_videos.py [--out runs/heldout720]

The figures in README.md and the model card that say "held-out 720p" use these videos.
"""
import argparse
from pathlib import Path

from hypergs_blender.bench.scale import make_pan_video
from hypergs_blender.io.images import read_image
from hypergs_blender.training.photos import load_photo_cache
from hypergs_blender.training.sources import DEFAULT_ROOT


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=DEFAULT_ROOT, help="the data folder of `hypergs prepare-data`")
    parser.add_argument("--out", default="runs/heldout720")
    args = parser.parse_args()
    data, out_dir = Path(args.data), Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    _, names, _ = load_photo_cache(data / "photos_val_cache.npz")
    for name in names:
        image = read_image(data / "photos" / name, max_short_side=1080)
        out = out_dir / (Path(name).stem.split("__")[-1][:20] + ".mp4")
        print(make_pan_video(out, seconds=2, width=1280, height=720, fps=24, crf=16, image=image))


if __name__ == "__main__":
    main()
