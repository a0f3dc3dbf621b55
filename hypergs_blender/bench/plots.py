"""Plots and tables from the benchmark reports: reads docs/bench/*.json (written by
`hypergs bench vs-fit|vs-x265|scale ... -o docs/bench/NAME.json`) and writes, per report,
docs/NAME.png, plus docs/bench/tables.md with every report's Markdown table (machine and date in
each table's first line).

    hypergs bench plots [--bench docs/bench] [--out docs]

- vs-fit: PSNR against encode seconds per frame (log), one panel per frames spec: per-frame fitting
  from random (circles, dotted) and from the Gaussian grid (triangles, solid) at each iteration count,
  the feedforward prediction (star) and feedforward + refine K (squares, dashed), one colour per
  Gaussian count; means over the videos.
- vs-x265: PSNR against bits per pixel (log), one panel per video: x265 at each CRF, and ours at each
  .hgs bit depth (one line per N and refine K).
- scale: resident memory against frames encoded (now and peak), the bounded-memory evidence.
Reports of other kinds (no "bench" key, e.g. `bench codec -o`) are skipped with a message.
"""
from __future__ import annotations

import json
from pathlib import Path


def _subtitle(report: dict) -> str:
    m, s = report["machine"], report.get("settings", {})
    where = m.get("gpu") or m.get("cpu", "?")
    return (f"{m.get('date', '?')[:10]} · {where} ({m.get('cores', '?')} cores, device {m.get('device', 'cpu')}) · "
            f"encoder {s.get('encoder', '?')}")


def _psnr_panel(ax, xlabel: str, title: str) -> None:
    """A panel of PSNR against a cost on a log axis (time, bits), as vs-fit and vs-x265 draw them."""
    ax.set_xscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("PSNR (dB)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best", framealpha=0.6)


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_vs_fit(report: dict, path: Path) -> None:
    import matplotlib.pyplot as plt
    summary = report["summary"]
    sizes = list(dict.fromkeys(g["size"] for g in summary))
    fig, axes = plt.subplots(1, len(sizes), figsize=(6.2 * len(sizes), 4.8), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = {"random": ("o", ":"), "grid": ("^", "-")}
    for ax, size in zip(axes[0], sizes):
        groups = [g for g in summary if g["size"] == size]
        for i, g in enumerate(groups):
            c = colours[i % len(colours)]
            n = "/".join(str(v) for v in g["n"])
            for init, rungs in g["fit"].items():
                if not rungs:
                    continue
                marker, line = styles.get(init, ("o", "-"))
                ax.plot([f["seconds"] for f in rungs], [f["psnr"] for f in rungs], marker + line, color=c,
                        markersize=4, alpha=0.8, label=f"fitting from {init} N={n}")
                for f in rungs:
                    ax.annotate(str(f["iters"]), (f["seconds"], f["psnr"]), fontsize=6, color=c,
                                xytext=(3, -9), textcoords="offset points")
            ff = g["feedforward"]
            ax.plot([ff["seconds"]], [ff["psnr"]], "*", color=c, markersize=13, label=f"ours N={n}")
            if g["refine"]:
                xs = [ff["seconds"]] + [r["seconds"] for r in g["refine"]]
                ys = [ff["psnr"]] + [r["psnr"] for r in g["refine"]]
                ax.plot(xs, ys, "s--", color=c, markersize=4, label=f"ours + refine N={n}")
                for r in g["refine"]:
                    ax.annotate(f"K={r['k']}", (r["seconds"], r["psnr"]), fontsize=7, color=c,
                                xytext=(3, 4), textcoords="offset points")
        res = ", ".join(groups[0]["resolution"]) if groups else ""
        _psnr_panel(ax, "encode seconds per frame (log)", f"frames {size} ({res})")
    fig.suptitle(f"PSNR vs encode time: feedforward, + refine, per-frame fitting\n{_subtitle(report)}", fontsize=10)
    _save(fig, path)


def plot_vs_x265(report: dict, path: Path) -> None:
    import matplotlib.pyplot as plt
    videos = report["videos"]
    fig, axes = plt.subplots(1, len(videos), figsize=(6.2 * len(videos), 4.8), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    codec = report["settings"].get("codec", "x265")
    for ax, v in zip(axes[0], videos):
        ref = sorted(v["x265"], key=lambda r: r["bpp"])
        ax.plot([r["bpp"] for r in ref], [r["psnr"] for r in ref], "k^-", label=f"{codec} (CRF)")
        for r in ref:
            ax.annotate(str(r["crf"]), (r["bpp"], r["psnr"]), fontsize=7, xytext=(3, -9), textcoords="offset points")
        for i, row in enumerate(v["ours"]):
            c = colours[i % len(colours)]
            hg = sorted(row["hgs"], key=lambda h: h["bpp"])
            label = f"ours N={row['n']}" + (f" + refine {row['refine']}" if row["refine"] else "")
            ax.plot([h["bpp"] for h in hg], [h["psnr"] for h in hg], "o-", color=c, label=label)
            for h in hg:
                ax.annotate(f"{h['bits']}b", (h["bpp"], h["psnr"]), fontsize=7, color=c, xytext=(3, 3),
                            textcoords="offset points")
        _psnr_panel(ax, "bits per pixel (log)",
                    f"{Path(v['path']).stem}: {v['width']}x{v['height']}, {v['frames']} frames")
    fig.suptitle(f"PSNR vs bpp: .hgs at each bit depth vs {codec}\n{_subtitle(report)}", fontsize=10)
    _save(fig, path)


def plot_scale(report: dict, path: Path) -> None:
    import matplotlib.pyplot as plt
    e = report["encode"]
    trace = e["rss_trace"]
    fig, ax = plt.subplots(figsize=(6.2, 4.2))
    ax.plot([t[0] for t in trace], [t[1] for t in trace], "-", label="resident now")
    ax.plot([t[0] for t in trace], [t[2] for t in trace], "-", label="peak so far")
    ax.axhline(e["rss_baseline_mb"], color="grey", ls=":", label="before the first frame")
    ax.set_xlabel("frames encoded")
    ax.set_ylabel("resident memory (MiB)")
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    src = report["source"]
    ax.set_title(f"memory while encoding {e['frames']} frames of {src['width']}x{src['height']} "
                 f"({e['fps']:.3g} frames/s)\n{_subtitle(report)}", fontsize=9)
    _save(fig, path)


PLOTTERS = {"vs-fit": plot_vs_fit, "vs-x265": plot_vs_x265, "scale": plot_scale}
TITLES = {"vs-fit": "Feedforward vs refine vs per-frame fitting", "vs-x265": "Matched quality against x265",
          "scale": "Scale: a long video end to end"}


def make_plots(bench_dir, out_dir, log=print) -> list[Path]:
    """Every docs/bench/*.json report -> out_dir/<name>.png and bench_dir/tables.md; the files written."""
    import matplotlib
    matplotlib.use("Agg")
    bench_dir, out_dir = Path(bench_dir), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written, tables = [], []
    for path in sorted(bench_dir.glob("*.json")):
        try:
            report = json.loads(path.read_text())
        except (OSError, ValueError) as e:
            log(f"{path}: skipped (not JSON: {e})")
            continue
        kind = report.get("bench") if isinstance(report, dict) else None
        if kind not in PLOTTERS:
            log(f"{path}: skipped (not a vs-fit / vs-x265 / scale report)")
            continue
        png = out_dir / f"{path.stem}.png"
        PLOTTERS[kind](report, png)
        written.append(png)
        log(f"{path} -> {png}")
        if report.get("table"):
            tables.append(f"## {TITLES[kind]} (`{path.name}`, plot `{png.name}`)\n\n{report['table']}\n")
    if tables:
        md = bench_dir / "tables.md"
        md.write_text("# Benchmark tables\n\nWritten by `hypergs bench plots` from the JSON reports beside this file.\n\n"
                      + "\n".join(tables))
        written.append(md)
        log(f"tables -> {md}")
    return written
