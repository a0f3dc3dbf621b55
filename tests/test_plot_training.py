"""tools/plot_training.py: a run continuing a chain whose logs are gone (a fresh machine) is plotted after
the chain as its CSV holds it."""
import json
import sys

import plot_training


def write_log(run, evals):
    run.mkdir()
    lines = [dict(step=s, wall=cpu, cpu=cpu, loss=0.1, rss_mb=700) for s, cpu, _ in evals]
    lines += [dict(step=s, wall=cpu, cpu=cpu, eval={"val_n1024": v, "val_n4096": v + 6}) for s, cpu, v in evals]
    (run / "log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))


def plot(monkeypatch, *argv):
    monkeypatch.setattr(sys, "argv", ["plot_training.py", *map(str, argv)])
    plot_training.main()


def test_earlier_csv_round_trips_and_a_new_run_continues_its_chain(tmp_path, monkeypatch):
    write_log(tmp_path / "first", [(500, 360.0, 29.0), (1000, 720.0, 29.5)])
    write_log(tmp_path / "second", [(400, 180.0, 30.0)])
    plot(monkeypatch, tmp_path / "first", tmp_path / "second", "--chain", "--out", tmp_path / "logs.png")
    both = (tmp_path / "logs.csv").read_text()
    assert "second,400,0.250,0.050,val_n1024,30.0" in both  # 720 + 180 CPU seconds
    write_log(tmp_path / "third", [(100, 360.0, 31.0)])
    plot(monkeypatch, "--chain", "--earlier", tmp_path / "logs.csv", "--out", tmp_path / "again.png")
    assert (tmp_path / "again.csv").read_text() == both  # the CSV alone reproduces itself
    plot(monkeypatch, tmp_path / "third", "--chain", "--earlier", tmp_path / "logs.csv", "--out", tmp_path / "all.png")
    rows = (tmp_path / "all.csv").read_text().splitlines()
    assert rows[:len(both.splitlines())] == both.splitlines()
    assert rows[-2:] == ["third,100,0.350,0.100,val_n1024,31.0", "third,100,0.350,0.100,val_n4096,37.0"]
    assert (tmp_path / "all.png").stat().st_size > 0


def test_a_metric_that_starts_on_the_way_is_plotted_from_there(tmp_path, monkeypatch):
    # train --ema given to a resumed run: its evaluations gain ema_* keys from that step on
    write_log(tmp_path / "run", [(500, 360.0, 29.0), (1000, 720.0, 29.5)])
    log = tmp_path / "run" / "log.jsonl"
    log.write_text(log.read_text() + json.dumps(dict(step=1500, wall=1080.0, cpu=1080.0, eval={
        "val_n1024": 29.7, "val_n4096": 35.7, "ema_val_n1024": 29.8})) + "\n")
    plot(monkeypatch, tmp_path / "run", "--out", tmp_path / "curve.png")
    rows = (tmp_path / "curve.csv").read_text().splitlines()
    assert [r for r in rows if ",ema_" in r] == ["run,1500,0.300,0.300,ema_val_n1024,29.8"]
    assert sum(",val_n1024," in r for r in rows) == 3
