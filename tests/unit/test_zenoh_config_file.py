"""`twinmesh --config FILE`: a Zenoh configuration file applied over twinmesh's own settings."""
from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from devices.cli.main import main
from mesh.fabric.settings import LOCAL_LEASE_MS, ConfigFileError, MeshSettings, config_overrides


def _file(tmp_path, text: str) -> str:
    path = tmp_path / "zenoh.json5"
    path.write_text(text)
    return str(path)


def test_the_files_values_win_over_twinmeshs_and_the_rest_stays(tmp_path):
    path = _file(tmp_path, "{ // Zenoh's own format: comments, unquoted keys\n"
                           " transport: { link: { tx: { lease: 20000 } }, unicast: { accept_pending: 500 } } }")
    overrides = config_overrides(path)
    assert dict(overrides) == {"transport/link/tx/lease": "20000", "transport/unicast/accept_pending": "500"}
    client = MeshSettings(overrides=overrides).zenoh_config()
    assert json.loads(client.get_json("transport/link/tx/lease")) == 20000  # twinmesh's own is LOCAL_LEASE_MS
    assert json.loads(MeshSettings().zenoh_config().get_json("transport/link/tx/lease")) == LOCAL_LEASE_MS
    router = MeshSettings(mode="router", connect=(), listen=("tcp/127.0.0.1:7447",), overrides=overrides)
    conf = router.zenoh_config()
    assert json.loads(conf.get_json("transport/unicast/accept_pending")) == 500
    assert json.loads(conf.get_json("transport/unicast/max_sessions")) > 1000  # twinmesh's, untouched


@pytest.mark.parametrize("text, named", [
    ("{ transport: { link: { tx: { lese: 1 } } } }", "transport/link/tx/lese = 1: unknown key"),
    ('{ transport: { link: { tx: { lease: "long" } } } }', "transport/link/tx/lease"),
    ('{ mode: "peer" }', "sets mode: twinmesh sets these itself"),
    ("{ transport: ", "is not JSON5"),
    ("[1, 2]", "must hold an object"),
])
def test_a_file_that_cannot_apply_is_named_with_its_problem(tmp_path, text, named):
    with pytest.raises(ConfigFileError, match=named.replace("[", r"\[")):
        config_overrides(_file(tmp_path, text))


def test_the_cli_refuses_a_bad_file_before_starting_anything(tmp_path):
    result = CliRunner().invoke(main, ["--config", _file(tmp_path, "{ scouting: { multicast: { enabled: 3 } } }"),
                                       "things"])
    assert result.exit_code == 2
    assert "scouting/multicast/enabled = 3" in result.output
    missing = CliRunner().invoke(main, ["--config", str(tmp_path / "absent.json5"), "things"])
    assert missing.exit_code == 2 and "cannot read the Zenoh config file" in missing.output
