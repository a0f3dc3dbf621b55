"""`hypergs bench encode`: the rows it reports are the layouts the encoder uses at each size."""
import json

from hypergs_blender.bench.encode import bench_encode
from hypergs_blender.commands.cli import main


def test_bench_encode_rows_follow_the_layouts():
    report = bench_encode(backends=("onnx",), counts=(64, 256), presets=("draft",), sizes=("256", "720p"),
                          frames=2, large_frames=1, repeats=1)
    rows = {(r["size"], r["setting"]): r for r in report["rows"]}
    assert set(rows) == {("256²", "N = 64"), ("256²", "N = 256"), ("720p", "draft")}
    assert rows[("256²", "N = 256")]["gaussians"] == 256
    assert rows[("720p", "draft")]["gaussians"] == 160 * 90  # cells of 8 px
    for r in rows.values():
        assert r["s_per_frame"] > 0 and abs(r["frames_per_s"] * r["s_per_frame"] - 1) < 0.02
        assert r["cpu_s_per_frame"] > 0
    assert "| 720p | draft | 14,400 | network-onnx |" in report["table"]


def test_bench_encode_command_writes_its_report(tmp_path, capsys):
    out = tmp_path / "encode.json"
    main(["bench", "encode", "--sizes", "256", "--gaussians", "64", "--backends", "torch", "--frames", "1",
          "--repeats", "1", "--threads", "1", "--precision", "bfloat16", "-o", str(out)])
    assert "| 256² | N = 64 | 64 | network-torch-bfloat16 |" in capsys.readouterr().out
    settings = json.loads(out.read_text())["settings"]
    assert (settings["threads"], settings["precision"]) == (1, "bfloat16")
