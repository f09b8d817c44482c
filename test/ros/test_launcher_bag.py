"""``recorder: {format: bag}``: the launcher's recorder writes a rosbag2 bag directory, which
``ros2 bag info`` (ours) reads from its metadata.yaml with the counts an independent read of the
MCAP file gives; the config spellings and their one-line refusals."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sdhn_bringup.launch_graph import node_parameters
from sdhn_bringup.launch_load import LaunchConfigError, load_config, resolve
from sdhn_sim.recording.reader import read_recording

from .processes import ROS2, node_processes

LAUNCH = [sys.executable, "-m", "sdhn_bringup", "configs/launch/deploy-tiny.yaml"]
MODEL = Path(__file__).resolve().parents[2] / "models" / "maif-tiny-sdhn"


def test_recorder_spellings(tmp_path: Path) -> None:
    config = tmp_path / "launch.yaml"
    config.write_text(f"env: maif-tiny\nweights: {MODEL}\nrecorder: {{format: bag}}\n")
    cfg = load_config(config, [])
    assert cfg.recorder and cfg.recorder_format == "bag"
    cfg.run_dir = str(tmp_path / "run")
    out = node_parameters(resolve(cfg))["/sdhn/recorder"]["output"]
    assert out == str((tmp_path / "run" / "recording").resolve()), out
    w = [f"weights={MODEL}", "env=maif-tiny"]
    assert load_config(None, [*w, "recorder.format=bag"]).recorder_format == "bag"
    assert load_config(None, [*w, "recorder=true"]).recorder_format == "mcap"
    assert not load_config(None, [*w, "recorder={enabled: false}"]).recorder
    with pytest.raises(LaunchConfigError, match=r"recorder.format: got 'rosbag'; allowed: mcap"):
        load_config(None, [*w, "recorder.format=rosbag"])
    with pytest.raises(LaunchConfigError, match=r"recorder.compression: unknown field"):
        load_config(None, [*w, "recorder.compression=zstd"])


def test_launcher_writes_a_bag_directory(weights: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    cmd = [*LAUNCH, "--set", f"weights={weights}", "--set", f"run_dir={run}", "--set",
           "recorder.format=bag", "--set", "episodes=1", "--set", "max_steps=20",
           "--set", "team_ns=/sdhn_bag"]
    with node_processes(cmd) as (launcher,):
        launcher.proc.wait(timeout=180)
    assert launcher.proc.returncode == 0, launcher.output
    bag = run / "recording"
    assert f"recording: {bag}" in launcher.output, launcher.output
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == ["recording_0.mcap"], meta["relative_file_paths"]
    counts = read_recording(bag / "recording_0.mcap").topics()
    assert counts["/sdhn_bag/state"] == 21, counts  # step 0 .. 20 of the one episode
    info = subprocess.run([*ROS2, "bag", "info", str(bag)], capture_output=True, text=True,
                          timeout=60, check=False)
    assert info.returncode == 0, info.stderr
    assert f"Messages:          {sum(counts.values())}" in info.stdout, info.stdout
    for topic, n in counts.items():
        assert f"Topic: {topic} | " in info.stdout and f"| Count: {n} |" in info.stdout
