"""tools/eval_rows.py: every row is a `hypergs eval` the command line takes, each design's rows are those of
docs/eval, and the comparison counts the clips that gained."""
import json
from pathlib import Path

import eval_rows
import pytest

from hypergs_blender.commands.cli import build_parser

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", sorted(eval_rows.ALL_ROWS))
def test_each_row_is_an_eval_the_command_line_takes(name):
    row = eval_rows.ALL_ROWS[name]
    videos = [a for a in row if a.endswith(".mp4")]  # the dev clips and held-out pans need not be here (CI): the sample
    assert videos in (eval_rows.DEV, eval_rows.HELD) and row[:len(videos)] == videos
    args = build_parser().parse_args(["eval", str(REPO / "hypergs_blender/samples/sample.mp4"), *row[len(videos):],
                                      "--weights", str(REPO / "hypergs_blender/weights"), "--json"])
    assert args.command == "eval"
    if name.startswith("transformer_"):
        assert args.model == "hypergs_transformer" and args.frames == 8
        assert args.grid == (int(name[-1]),) * 2 and args.gaussians == int(name.split("_n")[1].split("_")[0])


def test_each_design_has_the_rows_docs_eval_holds():
    reports = {path.stem for path in (REPO / "docs/eval").glob("*.json")}
    assert set(eval_rows.TRANSFORMER_ROWS) == {name for name in reports if name.startswith("transformer_")}
    assert set(eval_rows.ROWS) <= reports and not set(eval_rows.ROWS) & set(eval_rows.TRANSFORMER_ROWS)


def report(psnrs, seams=None):
    clips = [dict(video=f"clip{i}.mp4", psnr=p, seam_ratio=None if seams is None else seams[i]) for i, p in enumerate(psnrs)]
    return dict(videos=clips, mean=dict(psnr=sum(psnrs) / len(psnrs), temporal=dict(delta_psnr=25.0)))


def test_compare_counts_the_clips_that_gained_and_the_largest_seam(tmp_path, capsys):
    old, new = tmp_path / "old", tmp_path / "new"
    old.mkdir(), new.mkdir()
    (old / "transformer_dev_n1000_grid2.json").write_text(json.dumps(report([30.0, 32.0], [1.02, 1.05])))
    (new / "transformer_dev_n1000_grid2.json").write_text(json.dumps(report([30.2, 31.9], [1.03, 1.08])))
    (new / "dev_n1000.json").write_text(json.dumps(report([28.0, 29.0])))  # no report before it: figures alone
    eval_rows.compare(old, new)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("dev_n1000 ") and "|" not in lines[0] and "seams" not in lines[0]
    assert "31.050 dB" in lines[1] and "seams max 1.080" in lines[1] and "seams max 1.050" in lines[1]
    assert lines[1].endswith("+0.050 dB, 1 of 2 clips up (worst -0.100)")
