"""Where a launch file's relative paths point: the shipped graphs (``configs/launch/``) name their
weights from the repository root and must run from any working directory; a launch file kept
elsewhere names them from its own folder; a ``--set`` path is the command line's, read from the
current directory. And the launcher says how the actors act, from the config it runs."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sdhn_bringup.launch_config import describe_actions
from sdhn_bringup.launch_graph import node_parameters
from sdhn_bringup.launch_load import LaunchConfigError, file_base, load_config

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "configs" / "launch" / "deploy-tiny.yaml"
TINY_WEIGHTS = REPO / "models" / "maif-tiny-sdhn" / "actor.safetensors"


def test_a_shipped_graph_resolves_its_weights_from_another_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # nothing named models/ here
    cfg = load_config(TINY, ["run_dir=here"])
    assert Path(cfg.weights) == TINY_WEIGHTS
    assert Path(cfg.run_dir).resolve() == tmp_path / "here"  # --set: the current directory


def test_a_launch_file_outside_configs_launch_reads_paths_from_its_folder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    mine = tmp_path / "mine"
    (mine / "w").mkdir(parents=True)
    shutil.copy(TINY_WEIGHTS, mine / "w" / "actor.safetensors")
    shutil.copy(TINY_WEIGHTS.with_suffix(".json"), mine / "w" / "actor.json")
    graph = mine / "graph.yaml"
    graph.write_text(yaml.safe_dump({"env": "maif-tiny", "weights": "w", "run_dir": "out",
                                     "trainer": {}}))
    monkeypatch.chdir(REPO)  # the repository root holds no w/: only the file's folder does
    cfg = load_config(graph, [])
    assert Path(cfg.weights) == mine / "w" / "actor.safetensors"
    assert Path(cfg.run_dir) == mine / "out"
    assert file_base(graph) == mine
    assert file_base(TINY) == REPO


def test_a_relative_path_that_is_not_there_is_named_with_where_it_was_looked_for(
        tmp_path: Path) -> None:
    graph = tmp_path / "graph.yaml"
    graph.write_text("env: maif-tiny\nweights: nowhere\n")
    with pytest.raises(LaunchConfigError, match=f"weights: {tmp_path / 'nowhere'} does not exist"):
        load_config(graph, [])


def test_the_launcher_runs_a_shipped_graph_from_another_directory(tmp_path: Path) -> None:
    """The user's command, from outside the repository (the config printed, nothing started)."""
    r = subprocess.run([sys.executable, "-m", "sdhn_bringup", str(TINY), "--print-config"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=60, check=False)
    assert r.returncode == 0, r.stderr
    assert Path(yaml.safe_load(r.stdout)["weights"]) == TINY_WEIGHTS


@pytest.mark.parametrize(("sets", "says"), [
    ([], "greedy, with stall breaking (rule 2,10,2), with dead reckoning"),  # the card's mode
    (["dead_reckoning=false"], "greedy, with stall breaking (rule 2,10,2)"),
    (["final_approach=true", "dead_reckoning=false"],
     "greedy, with stall breaking (rule 2,10,2) and the final approach"),
    (["break_stalls=false", "stall_rule=", "dead_reckoning=false"], "greedy"),
    (["break_stalls=false", "stall_rule=", "greedy=false", "temperature=0.5",
      "dead_reckoning=false"], "sampled at temperature 0.5"),
])
def test_the_demo_graph_is_described_as_it_runs(sets: list[str], says: str) -> None:
    cfg = load_config(REPO / "configs" / "launch" / "deploy-maif10.yaml", sets)
    assert describe_actions(cfg) == says


def _model(tmp_path: Path, deploy: dict[str, object] | None) -> Path:
    """A copy of the maif-tiny weights with a card whose deployment mode is ``deploy``."""
    folder = tmp_path / "model"
    folder.mkdir()
    shutil.copy(TINY_WEIGHTS, folder / "actor.safetensors")
    shutil.copy(TINY_WEIGHTS.with_suffix(".json"), folder / "actor.json")
    if deploy is not None:
        (folder / "card.json").write_text(json.dumps(
            {"env": "maif-tiny", "heldout_large": {"deploy": deploy}}))
    return folder


@pytest.mark.parametrize(("deploy", "sets", "reckons"), [
    ({"greedy": True, "dead_reckoning": True}, [], True),  # the card's mode: deployed with it
    ({"greedy": True, "dead_reckoning": True}, ["dead_reckoning=false"], False),  # refused
    ({"greedy": True}, [], False),  # the card's mode without it
    (None, [], False),  # weights without a card
    (None, ["dead_reckoning=true"], True),
])
def test_dead_reckoning_deploys_as_the_card_says_unless_the_config_chooses(
        tmp_path: Path, deploy: dict[str, object] | None, sets: list[str], reckons: bool) -> None:
    model = _model(tmp_path, deploy)
    cfg = load_config(TINY, [f"weights={model}", f"run_dir={tmp_path / 'run'}", *sets])
    assert cfg.dead_reckoning is reckons
    actors = [v for k, v in node_parameters(cfg).items() if k.endswith("/actor")]
    assert len(actors) == 4 and all(a["dead_reckoning"] is reckons for a in actors)
    assert describe_actions(cfg).endswith("with dead reckoning") is reckons


def test_dead_reckoning_outside_a_deployment_is_refused() -> None:
    with pytest.raises(LaunchConfigError, match="dead_reckoning: applies only to deploy mode"):
        load_config(TINY, ["mode=train", "weights=", "dead_reckoning=true", "greedy=true"])


@pytest.mark.parametrize("model", ["rware-3-mappo", "rware-3-sdhn", "rware-tiny-2ag-mappo",
                                   "rware-tiny-4ag-mappo"])
@pytest.mark.parametrize(("sets", "reckons"), [([], True), (["dead_reckoning=false"], False)])
def test_an_rware_card_names_dead_reckoning_in_its_deployment_mode(
        tmp_path: Path, model: str, sets: list[str], reckons: bool) -> None:
    # every RWARE card deploys it (measured under latency) unless the config refuses it
    env = json.loads((Path("models") / model / "card.json").read_text())["env"]
    cfg = load_config(TINY, [f"env={env}", f"weights=models/{model}",
                             f"run_dir={tmp_path / 'run'}", *sets])
    assert cfg.dead_reckoning is reckons
    assert describe_actions(cfg).endswith("with dead reckoning") is reckons


def test_an_rware_deployment_takes_dead_reckoning(tmp_path: Path) -> None:
    cfg = load_config(TINY, ["env=rware-tiny-2ag", "weights=models/rware-tiny-2ag-mappo",
                             f"run_dir={tmp_path / 'run'}", "dead_reckoning=true"])
    actors = [v for k, v in node_parameters(cfg).items() if k.endswith("/actor")]
    assert len(actors) == 2 and all(a["dead_reckoning"] is True for a in actors)
    assert all(a["env"] == "rware-tiny-2ag" for a in actors)
