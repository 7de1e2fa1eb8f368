"""Bad input to `railhil run --external` and `railhil node`: one line `error: ...`, exit 2, no run folder left
behind (issue #17).  Nothing here opens a real-time run: every error is found before."""

import pytest
from conftest import DEFAULT, assert_one_line_error, railhil

from hil.runtime.realtime import external_nodes, hosts, resolve_bus_config
from hil.scenario import load_scenario


@pytest.mark.parametrize(("args", "needles"), [
    (("--external", "BECU9"), ("--external BECU9", "no node 'BECU9'", "BECU6")),
    (("--external", "BECU3", "--external", "BECU3"), ("--external BECU3", "given twice")),
    (("--external", "PLANT"), ("PLANT", "cannot be external", "ground truth")),
])
def test_external_naming_no_node_or_twice_is_one_line_and_leaves_no_folder(capsys, tmp_path, args, needles):
    out = tmp_path / "run"
    assert_one_line_error(*railhil(capsys, "run", DEFAULT, "--realtime", *args, "--out", out)[::2], *needles)
    assert not out.exists()

def test_external_without_realtime_is_one_line(capsys, tmp_path):
    out = tmp_path / "run"
    assert_one_line_error(*railhil(capsys, "run", DEFAULT, "--external", "BECU3", "--out", out)[::2],
                          "--external BECU3", "--realtime")
    assert not out.exists()

def test_external_in_the_scenario_file_is_checked_like_the_flag(tmp_path):
    from hil.errors import ScenarioError

    scenario = load_scenario(DEFAULT, sets=["nodes.BECU2.external=true"])
    assert external_nodes(scenario, ["BECU3"]) == ["BECU2", "BECU3"]
    with pytest.raises(ScenarioError, match="no node 'BECU9'"):
        external_nodes(load_scenario(DEFAULT, sets=["nodes.BECU9.external=true"]))
    every = ",".join(["PLANT", "DESK", "BCU"] + [f"BECU{i}" for i in range(1, 7)])
    with pytest.raises(ScenarioError, match="every node"):
        external_nodes(scenario, every.split(","))

@pytest.mark.parametrize(("args", "needles"), [
    (("BECU9", DEFAULT), ("node BECU9", "no node 'BECU9'", "BECU6")),
    (("BECU3,BECU3", DEFAULT), ("node BECU3", "given twice")),
    (("BECU3", DEFAULT, "-i", "socketcan", "-c", "nosuchcan0"), ("cannot open the python-can bus",
                                                                  "nosuchcan0")),
    (("BECU3", DEFAULT, "--duration", "0"), ("--duration 0", "> 0")),
])
def test_railhil_node_bad_input_is_one_line_exit_2(capsys, args, needles):
    assert_one_line_error(*railhil(capsys, "node", *args)[::2], *needles)

def test_an_external_run_uses_python_cans_default_group_unless_a_channel_is_named():
    from can.interfaces.udp_multicast import UdpMulticastBus

    scenario = load_scenario(DEFAULT)
    assert resolve_bus_config({}, scenario, external=True)["channel"] == UdpMulticastBus.DEFAULT_GROUP_IPv4
    assert resolve_bus_config({}, scenario)["channel"].startswith("239.255.")           # a group of its own
    assert resolve_bus_config({"channel": "239.1.2.3"}, scenario, external=True)["channel"] == "239.1.2.3"

def test_hosting_puts_the_ecus_in_one_process_and_the_plant_where_configured():
    names = ["PLANT", "DESK", "BCU", "BECU1", "BECU2"]
    grouped = load_scenario(DEFAULT)
    assert hosts(grouped, names) == {"PLANT": ("PLANT",), "ECUS": ("DESK", "BCU", "BECU1", "BECU2")}
    shared = load_scenario(DEFAULT, sets=["realtime.plant_process=shared"])
    assert hosts(shared, names) == {"NODES": tuple(names)}
    per_node = load_scenario(DEFAULT, sets=["realtime.hosting=per-node"])
    assert hosts(per_node, names) == {n: (n,) for n in names}
    assert hosts(grouped, ["DESK", "BCU"]) == {"ECUS": ("DESK", "BCU")}             # the plant external
