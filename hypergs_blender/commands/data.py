"""`hypergs prepare-data` (the training data under data/) and `hypergs preview-data` (a contact sheet of
training clips)."""
from __future__ import annotations

import sys

from ..io.images import write_image
from ..training.data import DEFAULT_SPEC, build_sources, contact_sheet
from ..training.prepare import VAL_PHOTO_COUNT, WALLPAPER_PACKAGES, prepare_photos, prepare_videos
from ..training.sources import DEFAULT_ROOT, make_batch
from ..io.images import IMAGE_EXTENSIONS
from . import options


def add_commands(subparsers) -> None:
    p = subparsers.add_parser(
        "prepare-data", help="download and cache the default training photos (and/or your videos)",
        description="Prepare training data under ROOT. With no --photos/--videos: the default set "
                    "(wallpaper photos from Debian packages -> photos_cache.npz + photos_val_cache.npz). "
                    "Idempotent: skips caches that are up to date unless --force.")
    p.add_argument("--root", default=DEFAULT_ROOT, type=options.run_folder, help="data folder (default: %(default)s)")
    p.add_argument("--photos", action="store_true", help="prepare the photo caches")
    p.add_argument("--photo-folder", default=None, type=options.input_folder,
                   help="build the photo caches from this folder of images instead of ROOT/photos "
                        "(no download)")
    p.add_argument("--videos", nargs="+", default=[], metavar="FOLDER", type=options.input_folder,
                   help="pre-extract a clip cache from each folder of videos (use videos=FOLDER in the "
                        "training spec)")
    p.add_argument("--packages", nargs="+", default=list(WALLPAPER_PACKAGES), metavar="PACKAGE", type=options.text,
                   help="the Debian packages whose images ROOT/photos is filled with when it is empty (default: "
                        "%(default)s; the bundled model trained on the first five)")
    p.add_argument("--val-photos", type=options.non_negative_int, default=VAL_PHOTO_COUNT,
                   help="held-out photos (default: %(default)s)")
    p.add_argument("--video-size", type=options.image_side, default=256,
                   help="cached clip side in pixels, about 2x the canvas (default: %(default)s)")
    p.add_argument("--video-frames", type=options.frame_count, default=16,
                   help="frames per cached clip (default: %(default)s)")
    p.add_argument("--clips-per-video", type=options.positive_int, default=8, help="(default: %(default)s)")
    p.add_argument("--force", action="store_true", help="rebuild caches that exist")
    p.set_defaults(func=_cmd_prepare)

    q = subparsers.add_parser("preview-data", help="write a contact sheet of random training clips",
                              description="One row per clip of make_batch, one column per frame.")
    q.add_argument("--spec", default=DEFAULT_SPEC, type=options.text, help="source spec (default: %(default)s)")
    q.add_argument("--root", default=DEFAULT_ROOT, type=options.text, help="data folder (default: %(default)s)")
    q.add_argument("--clips", type=options.positive_int, default=8)
    q.add_argument("--frames", type=options.frame_count, default=4)
    q.add_argument("--size", type=options.image_side, default=128)
    q.add_argument("--seed", type=options.non_negative_int, default=0)
    q.add_argument("--out", required=True, type=options.OutputFile(IMAGE_EXTENSIONS), help="image file to write (.png)")
    q.set_defaults(func=_cmd_preview)


def _cmd_prepare(args) -> None:
    do_photos = args.photos or args.photo_folder is not None or not args.videos
    if do_photos:
        prepare_photos(args.root, folder=args.photo_folder, force=args.force, val_count=args.val_photos,
                       packages=args.packages)
    for folder in args.videos:
        prepare_videos(folder, args.root, cache_size=args.video_size, cache_frames=args.video_frames,
                       clips_per_video=args.clips_per_video, force=args.force)
    sys.stdout.flush()


def _cmd_preview(args) -> None:
    sources = build_sources(args.spec, args.root)
    batch = make_batch(sources, args.seed, 0, 0, args.clips, args.frames, args.size)
    write_image(args.out, contact_sheet(batch))
    print(f"wrote {args.out}: {args.clips} clips x {args.frames} frames from {args.spec}")
