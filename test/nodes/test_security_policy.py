"""The SROS2 access-control policy (issue #26, docs/security.md): the shipped file allows exactly what the
suite's nodes do on the graph, over real DDS on loopback; the policy format by hand."""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from fiper_ros.cli import main
from fiper_ros.commands.security import Grants, differences, policy_xml, read_policy, resolve
from fiper_ros.launcher.config import load_launch

ROOT = Path(os.environ["FIPER_ROOT"])
POLICY = ROOT / "fiper_ros" / "config" / "sros2_policy.xml"
DEMO = ROOT / "fiper_ros" / "launch" / "demo.launch.yaml"


def test_the_shipped_policy_covers_exactly_the_topics_and_services_the_nodes_use(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)  # the demo's model and calibration: the installed ones, from any directory
    generated = tmp_path / "policy.xml"
    assert main(["security", str(DEMO), "-o", str(generated)]) == 0  # in a ROS domain of its own
    assert "6 enclaves written" in capsys.readouterr().out
    used = read_policy(generated.read_text())
    assert sorted(used) == sorted(spec.fqn for spec in load_launch(DEMO).nodes)  # every node, by its own name
    shipped = read_policy(POLICY.read_text())
    assert differences(shipped, used, ("the shipped policy", "the code")) == [], \
        "regenerate: fiper security -o fiper_ros/config/sros2_policy.xml"
    # what the suite's contract rests on, named in the graph and so in the policy
    fusion, supervisor = used["/fiper/fusion_node"], used["/fiper/supervisor_node"]
    assert "/fiper/alarm" in fusion.publish and {"/fiper/scores/rnd_oe", "/fiper/scores/ace"} <= fusion.subscribe
    assert "/fiper/fusion_node/reset" in fusion.reply
    assert "/fiper/alarm" in supervisor.subscribe and supervisor.request == frozenset({"/sim/halt"})
    assert all("/fiper/alarm" not in g.publish for n, g in used.items() if n != "/fiper/fusion_node")


def test_each_enclave_is_its_node_and_every_name_is_absolute() -> None:
    root = ET.parse(POLICY).getroot()  # noqa: S314 - our own file
    enclaves = root.findall("enclaves/enclave")
    assert enclaves
    for enclave in enclaves:
        (profile,) = enclave.findall("profiles/profile")
        assert enclave.get("path") == f"{profile.get('ns').rstrip('/')}/{profile.get('node')}"
        for names in profile:
            assert list(names), "an empty list is not valid SROS2"
            assert all(e.text.startswith("/") for e in names), [e.text for e in names]
            assert set(names.attrib.values()) == {"ALLOW"}


def test_a_policy_reads_back_as_written_and_differences_name_each_grant() -> None:
    policy = {"/fiper/fusion_node": Grants(publish=frozenset({"/fiper/alarm"}), reply=frozenset({"/fiper/x/reset"})),
              "/sup": Grants(subscribe=frozenset({"/fiper/alarm"}), request=frozenset({"/sim/halt"}))}
    text = policy_xml(policy, "by hand")
    assert "by hand" in text.splitlines()[1] and "<topics subscribe=\"ALLOW\">" in text
    assert read_policy(text) == policy
    fewer = {"/fiper/fusion_node": Grants(publish=frozenset({"/fiper/alarm"}))}
    assert differences(policy, fewer, ("a", "b")) == ["/sup: only in a",
                                                      "/fiper/fusion_node reply /fiper/x/reset: only in a"]
    assert differences(fewer, policy) == ["/sup: only in the second",
                                          "/fiper/fusion_node reply /fiper/x/reset: only in the second"]


def test_relative_names_resolve_as_sros2_does() -> None:
    assert resolve("/diagnostics", "/fiper", "fusion_node") == "/diagnostics"
    assert resolve("alarm", "/fiper", "fusion_node") == "/fiper/alarm"
    assert resolve("~reset", "/fiper", "fusion_node") == "/fiper/fusion_node/reset"
    assert resolve("~/reset", "/fiper/", "fusion_node") == "/fiper/fusion_node/reset"
    assert resolve("chatter", "/", "talker") == "/chatter"
    text = ('<policy version="0.2.0"><enclaves><enclave path="/a/n"><profiles><profile ns="/a" node="n">'
            '<topics publish="ALLOW"><topic>t</topic></topics><topics subscribe="DENY"><topic>u</topic></topics>'
            '<services reply="ALLOW"><service>~s</service></services></profile></profiles></enclave></enclaves>'
            '</policy>')
    assert read_policy(text) == {"/a/n": Grants(publish=frozenset({"/a/t"}), reply=frozenset({"/a/n/s"}))}
    with pytest.raises(ValueError, match="0.2.0"):
        read_policy('<policy version="0.1.0"/>')
