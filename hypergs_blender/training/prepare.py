"""`hypergs prepare-data`: the training data under data/, made once before training. The default
set is the wallpaper photos of a few Debian packages (fetched with apt-get download, unpacked with
dpkg -x), split into a training cache and a held-out validation cache; `--videos FOLDER` pre-extracts
short clips of the user's videos into a clip cache."""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from ..io.frames import iter_frames, probe
from ..errors import VideoError
from ..io.images import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS, downscale, list_images, read_image, resize_exact
from .photos import (PHOTO_CACHE, PHOTO_MAX_SHORT_SIDE, PHOTO_VAL_CACHE, PHOTOS_DIR, detail, load_photo_cache,
                     save_photo_cache)
from .sources import DEFAULT_ROOT, DataError, media_files
from .videos import CACHE_VERSION, video_cache_dir

WALLPAPER_PACKAGES = ("gnome-backgrounds", "mate-backgrounds", "ukui-wallpapers", "lomiri-wallpapers-16.04",
                      "lomiri-wallpapers-20.04", "plasma-workspace-wallpapers", "mypaint-data-extras")
VAL_PHOTO_COUNT = 4
# The default set's held-out photos: what _split_val chose from the first five packages, which every val figure
# and the held-out videos (tools/make_heldout_videos.py) have used since; pinned, so that a package added to the
# set trains rather than moves the validation.
DEFAULT_VAL_PHOTOS = ("lomiri-wallpapers-20.04__Kleiber_by_Lukas_Baubkus.jpg", "mate-backgrounds__Aqua.jpg",
                      "mate-backgrounds__Elephants_5640x3172.jpg", "mate-backgrounds__LadyBird.jpg")


def _thumb(image: np.ndarray, n: int = 32) -> np.ndarray:
    """Grey n x n thumbnail (box filtered), float64."""
    grey = image.astype(np.float32).mean(2)
    h, w = grey.shape
    ys = (np.arange(h) * n // h)
    xs = (np.arange(w) * n // w)
    out = np.zeros((n, n))
    np.add.at(out, (ys[:, None], xs[None, :]), grey)
    counts = np.zeros((n, n))
    np.add.at(counts, (ys[:, None], xs[None, :]), 1)
    return out / np.maximum(counts, 1)


def _stem_key(path: Path) -> str:
    """File name without variant suffixes (-l/-d, -dark/-light, a resolution) for grouping."""
    stem = path.stem.lower().split("__")[-1]
    stem = re.sub(r"([_-](\d+x\d+|l|d|light|dark|day|night))+$", "", stem)
    return stem


def _collect_photos(paths, log=print, max_short_side=PHOTO_MAX_SHORT_SIDE, min_short_side=128):
    """Decode, drop unreadable/flat/tiny images and duplicates; return [(path, image, info)] and
    group ids (near-duplicates and variants share a group, kept on one side of the split)."""
    records = []
    seen = {}
    for path in paths:
        data = Path(path).read_bytes()
        digest = hashlib.sha1(data).hexdigest()
        if digest in seen:
            log(f"  skip {Path(path).name}: same file as {Path(seen[digest]).name}")
            continue
        seen[digest] = path
        try:
            full = read_image(path)
            h, w = full.shape[:2]
            image = downscale(full, max_short_side) if min(h, w) > max_short_side else full
        except (VideoError, RuntimeError, OSError) as e:
            log(f"  skip {Path(path).name}: unreadable ({e})")
            continue
        if min(w, h) < min_short_side:
            log(f"  skip {Path(path).name}: too small ({w}x{h})")
            continue
        if detail(image) < 1.0:
            log(f"  skip {Path(path).name}: (almost) flat image")
            continue
        records.append({"path": Path(path), "image": image, "pixels": w * h, "digest": digest,
                        "thumb": _thumb(image)})
    # Near-duplicates (same picture at other sizes): keep the largest original.
    keep = []
    for rec in sorted(records, key=lambda r: -r["pixels"]):
        t = rec["thumb"]
        dup = None
        for other in keep:
            o = other["thumb"]
            if t.shape == o.shape and np.abs(t - o).mean() < 3.0 and \
                    abs(rec["image"].shape[1] / rec["image"].shape[0]
                        - other["image"].shape[1] / other["image"].shape[0]) < 0.02:
                dup = other
                break
        if dup is not None:
            log(f"  skip {rec['path'].name}: near-duplicate of {dup['path'].name}")
            continue
        keep.append(rec)
    keep.sort(key=lambda r: str(r["path"]))
    # Groups: correlated thumbnails (also inverted: light/dark variants) or the same name stem.
    parent = list(range(len(keep)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(keep)):
        for j in range(i):
            a, b = keep[i]["thumb"].ravel(), keep[j]["thumb"].ravel()
            corr = np.corrcoef(a, b)[0, 1] if a.std() > 0 and b.std() > 0 else 0.0
            if abs(corr) > 0.85 or _stem_key(keep[i]["path"]) == _stem_key(keep[j]["path"]):
                parent[find(i)] = find(j)
    groups = [find(i) for i in range(len(keep))]
    return keep, groups


def _split_val(keep, groups, val_count, pinned=DEFAULT_VAL_PHOTOS):
    """Held-out photos: val_count singleton groups (no variant of them is trained on): the `pinned` file names
    that are there first, then detailed JPEGs (photographs rather than graphics), chosen by a hash of the file
    name (stable)."""
    sizes = {g: groups.count(g) for g in groups}

    def rank(i):  # the pinned ones, then detailed JPEGs (photographs, not flat graphics)
        path = keep[i]["path"]
        photo = path.suffix.lower() in (".jpg", ".jpeg") and detail(keep[i]["image"]) >= 8.0
        return (path.name not in pinned, not photo, hashlib.sha1(path.name.encode()).hexdigest())

    order = sorted(range(len(keep)), key=rank)
    val = [i for i in order if sizes[groups[i]] == 1][:val_count]
    if len(val) < val_count:  # not enough singletons: take whole groups
        for i in order:
            if len(val) >= val_count:
                break
            if i not in val:
                val.extend(j for j in range(len(keep)) if groups[j] == groups[i] and j not in val)
    if len(keep) - len(val) < 1:
        val = val[:max(0, len(keep) - 1)]
    return sorted(val)


def package_images(root) -> list[tuple[Path, str]]:
    """The images (.jpg/.png/.webp files, not links) of a package unpacked into `root`, each with the name it is
    copied under. A Plasma wallpaper (NAME/contents/images/WxH.ext, one file per screen size, beside a screenshot
    and dark variants) gives its largest image only, as NAME_WxH.ext; any other image keeps its own name."""
    plasma, out = {}, []
    for f in sorted(Path(root).rglob("*")):
        if not f.is_file() or f.is_symlink() or f.suffix.lower() not in (".jpg", ".jpeg", ".png", ".webp"):
            continue
        if "contents" in f.parts[:-1]:
            size = re.fullmatch(r"(\d+)x(\d+)", f.stem)
            if f.parent.name == "images" and f.parent.parent.name == "contents" and size:
                name = f.parent.parent.parent.name
                pixels = int(size[1]) * int(size[2])
                if name not in plasma or pixels > plasma[name][0]:
                    plasma[name] = (pixels, f)
            continue
        out.append((f, f.name))
    out += [(f, f"{name}_{f.name}") for name, (_, f) in sorted(plasma.items())]
    return out


def _folder_manifest(paths, folder) -> list:
    out = []
    for p in paths:
        st = Path(p).stat()
        out.append([str(Path(p).relative_to(folder)), st.st_size, int(st.st_mtime)])
    return out


def prepare_videos(folder, root=DEFAULT_ROOT, cache_size: int = 256, cache_frames: int = 16,
                   clips_per_video: int = 8, force: bool = False, seed: int = 0, log=print) -> Path:
    """Decode random short clips of every video in `folder` into ROOT/videos_cache/NAME-HASH/:
    clips.npy (uint8 [N, cache_frames, cache_size, cache_size, 3], a square crop at a random
    position of the frame resized to short side cache_size) and index.json. Each clip has a random
    base stride (1-4 source frames) so that sampling strides reach further in time."""
    folder = Path(folder)
    files = media_files(folder, VIDEO_EXTENSIONS, f"--videos {folder}")
    cache = video_cache_dir(folder, root)
    params = {"cache_size": cache_size, "cache_frames": cache_frames,
              "clips_per_video": clips_per_video, "seed": seed}
    manifest = _folder_manifest(files, folder)
    index_path = cache / "index.json"
    if index_path.is_file() and not force:
        try:
            old = json.loads(index_path.read_text())
        except ValueError:
            old = {}
        if old.get("params") == params and old.get("files") == manifest and (cache / "clips.npy").is_file():
            log(f"videos: {cache} is up to date ({len(old['clips'])} clips of {len(files)} videos); "
                f"--force rebuilds it")
            return cache
    rng = np.random.default_rng([seed, 7])
    plan = []  # per video: (path, info, [(start, stride, crop)])
    for f in files:
        try:
            info = probe(f)
        except VideoError as e:
            log(f"  skip {f.name}: {e}")
            continue
        n = info.num_frames
        strides = [b for b in (1, 2, 3, 4) if (cache_frames - 1) * b + 1 <= n]
        if not strides:
            log(f"  skip {f.name}: {n} frames, fewer than the {cache_frames} a clip needs")
            continue
        k = min(clips_per_video, max(1, n // max(1, cache_frames // 2)))
        scale = cache_size / min(info.width, info.height)
        rw, rh = max(cache_size, round(info.width * scale)), max(cache_size, round(info.height * scale))
        clips = []
        for j in range(k):
            b = int(rng.choice(strides))
            span = (cache_frames - 1) * b + 1
            lo, hi = j * (n - span) // k, (j + 1) * (n - span) // k
            start = int(rng.integers(lo, hi + 1))
            crop = (int(rng.integers(0, rw - cache_size + 1)), int(rng.integers(0, rh - cache_size + 1)))
            clips.append((start, b, crop))
        plan.append((f, info, (rw, rh), clips))
    total = sum(len(c) for *_, c in plan)
    if total == 0:
        raise DataError(f"--videos {folder}: no usable videos")
    cache.mkdir(parents=True, exist_ok=True)
    tmp = cache / "clips.tmp.npy"
    arr = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint8,
                                    shape=(total, cache_frames, cache_size, cache_size, 3))
    entries = []
    row = 0
    t0 = time.time()
    for f, info, (rw, rh), clips in plan:
        wanted = {}  # frame index -> [(row, slot, crop)]
        for j, (start, b, crop) in enumerate(clips):
            entries.append({"video": str(f.relative_to(folder)), "start": start, "stride": b,
                            "crop": list(crop), "resized": [rw, rh]})
            for slot in range(cache_frames):
                wanted.setdefault(start + slot * b, []).append((row + j, slot, crop))
        try:
            for index, frame in iter_frames(f, sorted(wanted)):
                resized = resize_exact(frame, rw, rh)
                for r, slot, (x0, y0) in wanted[index]:
                    arr[r, slot] = resized[y0:y0 + cache_size, x0:x0 + cache_size]
        except VideoError as e:
            log(f"  warning {f.name}: {e} (its clips keep the frames decoded so far)")
        row += len(clips)
        log(f"  {f.name}: {info.width}x{info.height}, {info.num_frames} frames -> {len(clips)} clips")
    arr.flush()
    del arr
    os.replace(tmp, cache / "clips.npy")
    index_path.write_text(json.dumps({"version": CACHE_VERSION, "folder": str(folder.resolve()),
                                      "params": params, "files": manifest, "clips": entries}, indent=1))
    log(f"videos: wrote {total} clips x {cache_frames} frames at {cache_size}x{cache_size} from "
        f"{len(plan)} videos to {cache} ({(cache / 'clips.npy').stat().st_size / 1e6:.0f} MB, "
        f"{time.time() - t0:.0f} s)")
    return cache


def _run(cmd, cwd=None, timeout=900):
    try:
        return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return subprocess.CompletedProcess(cmd, 124, "", f"{cmd[0]} timed out after {timeout} s")


def download_wallpapers(dest, packages=WALLPAPER_PACKAGES, log=print) -> list[Path]:
    """apt-get download + dpkg -x the wallpaper packages; copy their .jpg/.png/.webp images (not
    .svg/.xml) into `dest` as PACKAGE__NAME.EXT, identical files once. Unavailable packages are
    skipped with a warning (after one `apt-get update` retry)."""
    if shutil.which("apt-get") is None or shutil.which("dpkg") is None:
        raise DataError("apt-get/dpkg not found (not a Debian-like system): put your own photos in a "
                        "folder and run `hypergs prepare-data --photo-folder FOLDER`")
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    copied, digests = [], set()
    with tempfile.TemporaryDirectory(prefix="hypergs-wallpapers-") as tmp:
        tmp = Path(tmp)
        debs = {}
        missing = list(packages)
        for attempt in range(2):
            for pkg in list(missing):
                before = set(tmp.glob("*.deb"))
                r = _run(["apt-get", "download", pkg], cwd=tmp)
                new = sorted(set(tmp.glob("*.deb")) - before)
                if r.returncode == 0 and new:
                    debs[pkg] = new[0]
                    missing.remove(pkg)
                    log(f"  downloaded {new[0].name} ({new[0].stat().st_size / 1e6:.1f} MB)")
            if not missing or attempt == 1:
                break
            log(f"  apt-get download could not fetch {', '.join(missing)}: running apt-get update")
            r = _run(["apt-get", "update"])
            if r.returncode != 0:
                log(f"  warning: apt-get update failed: {r.stderr.strip().splitlines()[-1:]}")
        for pkg in missing:
            log(f"  warning: package {pkg} is unavailable here; skipped")
        for pkg, deb in debs.items():
            root = tmp / pkg
            r = _run(["dpkg", "-x", str(deb), str(root)])
            if r.returncode != 0:
                log(f"  warning: dpkg -x {deb.name} failed: {r.stderr.strip()}; skipped")
                continue
            for f, name in package_images(root):
                digest = hashlib.sha1(f.read_bytes()).hexdigest()
                if digest in digests:
                    continue
                digests.add(digest)
                target = dest / f"{pkg}__{name}"
                shutil.copyfile(f, target)
                copied.append(target)
    log(f"  {len(copied)} images from {len(debs)} packages copied to {dest}")
    return copied


def prepare_photos(root=DEFAULT_ROOT, folder=None, force: bool = False, val_count: int = VAL_PHOTO_COUNT,
                   packages=WALLPAPER_PACKAGES, log=print) -> tuple[Path, Path]:
    """Fill ROOT/photos from the wallpaper `packages` (unless it has images, or `folder` is given),
    then write ROOT/photos_cache.npz (training) and ROOT/photos_val_cache.npz (val_count held-out
    photos). Skips caches that are up to date with the folder unless force (which rebuilds the
    caches, not the download)."""
    root = Path(root)
    train_path, val_path = root / PHOTO_CACHE, root / PHOTO_VAL_CACHE
    if folder is None:
        folder = root / PHOTOS_DIR
        if not list_images(folder):
            log(f"photos: downloading {len(packages)} wallpaper packages into {folder}")
            download_wallpapers(folder, packages, log=log)
        else:
            log(f"photos: using the images in {folder} (delete it to download them again)")
    folder = Path(folder)
    files = media_files(folder, IMAGE_EXTENSIONS, f"--photo-folder {folder}")
    manifest = {"folder": str(folder.resolve()), "files": _folder_manifest(files, folder),
                "val_count": val_count, "max_short_side": PHOTO_MAX_SHORT_SIDE}
    if train_path.is_file() and val_path.is_file() and not force:
        try:
            _, names, meta = load_photo_cache(train_path)
        except DataError:
            meta, names = {}, []
        if meta.get("manifest") == manifest:
            _, val_names, _ = load_photo_cache(val_path)
            log(f"photos: {train_path} ({len(names)} photos) and {val_path} ({len(val_names)}) are up "
                f"to date; --force rebuilds them")
            return train_path, val_path
        log(f"photos: {folder} changed since the caches were made; rebuilding them")
    t0 = time.time()
    log(f"photos: decoding {len(files)} images from {folder} (short side <= {PHOTO_MAX_SHORT_SIDE})")
    keep, groups = _collect_photos(files, log=log)
    if len(keep) < 2:
        raise DataError(f"{folder}: only {len(keep)} usable photos; need at least 2")
    val = _split_val(keep, groups, val_count)
    train = [i for i in range(len(keep)) if i not in val]
    meta = {"manifest": manifest}
    save_photo_cache(train_path, [keep[i]["image"] for i in train], [keep[i]["path"].name for i in train], meta)
    save_photo_cache(val_path, [keep[i]["image"] for i in val], [keep[i]["path"].name for i in val], meta)
    size_mb = (train_path.stat().st_size + val_path.stat().st_size) / 1e6
    log(f"photos: {len(train)} training photos -> {train_path}, {len(val)} held-out -> {val_path} "
        f"({size_mb:.0f} MB, {time.time() - t0:.0f} s)")
    log(f"  held out: {', '.join(keep[i]['path'].name for i in val)}")
    return train_path, val_path
