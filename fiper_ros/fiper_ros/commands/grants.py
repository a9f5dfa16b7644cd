"""What each participant of the suite does on the ROS graph: the grants of its SROS2 policy (docs/security.md).

Derived, never listed by hand. A node's grants follow from its module (one rule per node class below, with the
names of :mod:`fiper_ros.interface.topics` and the parameters the node runs with: its launch file's parameter
files and values, else the default it declares, which is the same constant; and its remaps); a tool's from the
names its code uses. They describe a node once it is ACTIVE (the scoring nodes subscribe their inputs on
activation).

The shipped policy is the union over every suite the project starts (:func:`shipped_deployments`): each shipped
launch file (``fiper launch``) with its default arguments and on each shipped model and calibration, the suites
of ``fiper replay`` and ``fiper collect --ros``, and the tools' own nodes (:func:`tool_grants`). So a node's grants are what it does in
any of them: ``ace_node`` subscribes ``/joint_states`` because the Stacking calibration's ACE maps joint
velocities. test/nodes/test_security_policy.py builds each of these nodes and tools and checks that its real
endpoints are exactly its grants.
"""
from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from fiper_msgs.msg import ActionChunkBatch
from fiper_ros.commands.errors import UsageError
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.calibration_file import declared_detectors
from fiper_ros.core.detectors import ACE, CALIBRATED, DETECTORS, RND_OE, info
from fiper_ros.core.kinematics import RobotModel
from fiper_ros.data_paths import resolve_data_path
from fiper_ros.errors import FiperError
from fiper_ros.interface.topics import (ACTIONS_TOPIC, ALARM_TOPIC, CAMERA_THIRD_TOPIC, CAMERA_TOPICS,
                                        CAMERA_WRIST_TOPIC, CLOCK_TOPIC, DIAGNOSTICS_TOPIC, EMBEDDING_TOPIC,
                                        EVENTS_TOPIC, JOINT_STATES_TOPIC, RESET_ALARM_SERVICE, SIM_ACTION_TOPIC,
                                        SIM_HALT_SERVICE, SIM_PROPRIO_TOPIC, SIM_RESET_SERVICE, STEP_SIGNALS_TOPIC,
                                        TOPICS, input_topic, relative, score_topic)
from fiper_ros.launcher.config import LaunchConfig, LaunchError, NodeSpec, load_launch
from fiper_ros.launcher.overrides import Overrides, apply

#: What every rclpy node has from ROS: its log and parameter events, its parameter and type description services.
ROSOUT = "/rosout"
PARAMETER_EVENTS = "/parameter_events"
NODE_SERVICES = ("~/describe_parameters", "~/get_parameter_types", "~/get_parameters", "~/get_type_description",
                 "~/list_parameters", "~/set_parameters", "~/set_parameters_atomically")
#: What a lifecycle node adds: its state machine's services and transition events.
LIFECYCLE_SERVICES = ("~/change_state", "~/get_available_states", "~/get_available_transitions", "~/get_state",
                      "~/get_transition_graph")
TRANSITION_EVENT = "~/transition_event"


class UnknownNode(UsageError):
    """A launch file names a node module this module has no rule for."""


@dataclass(frozen=True)
class Grants:
    """What one node does on the ROS graph: topics it publishes and subscribes, services it offers
    (``reply``) and calls (``request``); absolute names, or relative and private ones before :meth:`resolved`."""

    publish: frozenset[str] = field(default_factory=frozenset)
    subscribe: frozenset[str] = field(default_factory=frozenset)
    reply: frozenset[str] = field(default_factory=frozenset)
    request: frozenset[str] = field(default_factory=frozenset)

    @classmethod
    def of(cls, **names: Iterable[str]) -> Grants:
        """Grants from any iterables of names (``Grants.of(publish=[...])``)."""
        return cls(**{kind: frozenset(value) for kind, value in names.items()})

    def names(self, kind: str) -> list[str]:
        """The names of one kind (``publish``, ``subscribe``, ``reply``, ``request``), sorted."""
        return sorted(getattr(self, kind))

    def __or__(self, other: Grants) -> Grants:
        return Grants(*(getattr(self, f.name) | getattr(other, f.name) for f in fields(self)))

    def resolved(self, fqn: str, remaps: Iterable[tuple[str, str]] = ()) -> Grants:
        """Every name made absolute as rclpy does for node ``fqn`` (:func:`resolve`), then renamed by the node's
        ``remaps`` (``from``, ``to``: a whole name, as rcl matches it)."""
        namespace, node = split_node(fqn)
        renamed = {resolve(a, namespace, node): resolve(b, namespace, node) for a, b in remaps}

        def absolute(name: str) -> str:
            full = resolve(name, namespace, node)
            return renamed.get(full, full)

        return Grants(*(frozenset(map(absolute, getattr(self, f.name))) for f in fields(self)))


#: A policy: fully qualified node name -> its grants.
Policy = Mapping[str, Grants]


def split_node(fqn: str) -> tuple[str, str]:
    """``/ns/name`` -> (``/ns``, ``name``); the root namespace is ``/``."""
    namespace, _, name = fqn.rpartition("/")
    return namespace or "/", name


def resolve(name: str, namespace: str, node: str) -> str:
    """A topic or service name made absolute as rclpy (and SROS2) does: ``/x`` as is, ``~x`` under the node,
    ``x`` under its namespace."""
    if name.startswith("/"):
        return name
    base = namespace.rstrip("/")
    return f"{base}/{node}/{name[1:].lstrip('/')}" if name.startswith("~") else f"{base}/{name}"


def names_node(key: str, fqn: str) -> bool:
    """Whether a parameter file's node key names node ``fqn``, as rcl reads it: ``*`` one name token, ``**`` any
    number, a key without a leading ``/`` from the root."""
    pattern = re.escape("/" + key.lstrip("/")).replace(r"\*\*", ".*").replace(r"\*", "[^/]*")
    return re.fullmatch(pattern, fqn) is not None


def effective_parameters(spec: NodeSpec) -> dict[str, Any]:
    """The parameters node ``spec`` gets from its launch, as rcl and rclpy read its ``param`` entries: every
    entry's values (a file's, or values by name, which the launcher passes as a file keyed by the node's name)
    merged per node key, a later entry winning within a key; then the keys that name the node applied in the
    order each key first appeared (so a ``/**`` that came first yields to the node's own key, whatever comes
    later). What the node declares by default is not here."""
    keys: dict[str, dict[str, Any]] = {}
    for entry in spec.params:
        items = (yaml.safe_load(entry.read_text()) or {}).items() if isinstance(entry, Path) else [(spec.parameter_key, entry)]
        for key, content in items:
            values = content if not isinstance(entry, Path) else (content or {}).get("ros__parameters") or {}
            keys.setdefault("/" + str(key).lstrip("/"), {}).update(values)
    merged: dict[str, Any] = {}
    for key, values in keys.items():
        if names_node(key, spec.fqn):
            merged |= values
    return merged


# the rules, one per node class -----------------------------------------------------------------------------
Rule = Callable[[Mapping[str, Any]], Grants]


def ros_node(p: Mapping[str, Any]) -> Grants:
    """Every rclpy node; ``/clock`` under sim time."""
    return Grants.of(publish=(ROSOUT, PARAMETER_EVENTS), subscribe=(CLOCK_TOPIC,) if p.get("use_sim_time") else (),
                     reply=NODE_SERVICES)


def fiper_node(p: Mapping[str, Any]) -> Grants:
    """:class:`fiper_ros.nodes.base.FiperNode`: a lifecycle node with its ``/diagnostics``."""
    return ros_node(p) | Grants.of(publish=(TRANSITION_EVENT, DIAGNOSTICS_TOPIC), reply=LIFECYCLE_SERVICES)


def scoring_node(p: Mapping[str, Any], detector: str) -> Grants:
    """:class:`fiper_ros.nodes.detector_node.DetectorNode` of ``detector``: its score out, the rollout events and
    what the detector reads in."""
    return fiper_node(p) | Grants.of(publish=(relative(score_topic(detector)),),
                                     subscribe=(relative(EVENTS_TOPIC), relative(input_topic(info(detector).reads))))


def detector_node(p: Mapping[str, Any]) -> Grants:
    """``fiper_ros.nodes.detector_node``: the detector its ``detector`` parameter names."""
    if not p.get("detector"):
        raise LaunchError("detector is not set: the node's grants depend on its detector")
    return scoring_node(p, str(p["detector"]))


def calibration_dir(p: Mapping[str, Any]) -> Path:
    """The calibration a node loads (its ``calibration_dir``, by the path rule of the nodes)."""
    directory = p.get("calibration_dir", "")
    if not directory:
        raise LaunchError("calibration_dir is not set: the node's grants depend on its calibration")
    return resolve_data_path(directory)


def rnd_oe_node(p: Mapping[str, Any]) -> Grants:
    """``fiper_ros.nodes.rnd_oe_node``."""
    return scoring_node(p, RND_OE)


def ace_node(p: Mapping[str, Any]) -> Grants:
    """``fiper_ros.nodes.ace_node``: with a joint-velocity calibration also the joint states."""
    velocities = load_calibration(calibration_dir(p)).layout.action_space == ActionChunkBatch.ACTION_SPACE_JOINT_VELOCITY
    joints = (p.get("joint_state_topic", JOINT_STATES_TOPIC),) if velocities else ()
    return scoring_node(p, ACE) | Grants.of(subscribe=joints)


def fusion_node(p: Mapping[str, Any]) -> Grants:
    """``fiper_ros.nodes.fusion_node``: the scores of the detectors its calibration declares (none set: both)."""
    detectors = declared_detectors(calibration_dir(p)) if p.get("calibration_dir") else DETECTORS
    return fiper_node(p) | Grants.of(publish=(relative(ALARM_TOPIC),), reply=(RESET_ALARM_SERVICE,),
                                     subscribe=(relative(EVENTS_TOPIC), *(relative(score_topic(d)) for d in detectors)))


def supervisor_node(p: Mapping[str, Any]) -> Grants:
    """``fiper_ros.nodes.supervisor_node``: a plain node."""
    return ros_node(p) | Grants.of(publish=(DIAGNOSTICS_TOPIC,), subscribe=(p.get("alarm_topic", ALARM_TOPIC),
                                                                       p.get("events_topic", EVENTS_TOPIC)),
                                   request=(p.get("halt_service", SIM_HALT_SERVICE),))


def policy_node(p: Mapping[str, Any]) -> Grants:
    """``fiper_ros.nodes.policy_node`` (its :class:`~fiper_ros.publishing.FiperPublisher` also has the step signals'
    publisher, which it never uses)."""
    return fiper_node(p) | Grants.of(
        publish=(p.get("embedding_topic", EMBEDDING_TOPIC), p.get("action_chunks_topic", ACTIONS_TOPIC),
                 STEP_SIGNALS_TOPIC, p.get("action_topic", SIM_ACTION_TOPIC)),
        subscribe=(p.get("events_topic", EVENTS_TOPIC), p.get("wrist_image_topic", CAMERA_WRIST_TOPIC),
                   p.get("third_image_topic", CAMERA_THIRD_TOPIC), p.get("proprio_topic", SIM_PROPRIO_TOPIC)))


def bridge_node(p: Mapping[str, Any]) -> Grants:
    """``sim_bridge.bridge_node``: the cameras with ``images``, ``/clock`` with ``sim_time``."""
    images = (p.get("wrist_image_topic", CAMERA_WRIST_TOPIC), p.get("third_image_topic", CAMERA_THIRD_TOPIC))
    return fiper_node(p) | Grants.of(
        publish=(p.get("joint_state_topic", JOINT_STATES_TOPIC), p.get("proprio_topic", SIM_PROPRIO_TOPIC),
                 p.get("events_topic", EVENTS_TOPIC), *(images if p.get("images", True) else ()),
                 *((CLOCK_TOPIC,) if p.get("sim_time", False) else ())),
        subscribe=(p.get("action_topic", SIM_ACTION_TOPIC),), reply=(SIM_RESET_SERVICE, SIM_HALT_SERVICE))


def view_node(p: Mapping[str, Any]) -> Grants:
    """``fiper_ros.nodes.view_node`` (the live view, a plain node): it only reads the scores of its ``detectors``
    (every detector a calibration may declare, by default), the alarm and events, the diagnostics and its
    ``cameras``; it publishes its own diagnostics."""
    return ros_node(p) | Grants.of(publish=(DIAGNOSTICS_TOPIC,), subscribe=(
        *(relative(score_topic(d)) for d in p.get("detectors", CALIBRATED)), relative(ALARM_TOPIC),
        relative(EVENTS_TOPIC), DIAGNOSTICS_TOPIC, *p.get("cameras", CAMERA_TOPICS)))


#: Node module (a launch file's ``module``) -> its rule.
NODE_RULES: dict[str, Rule] = {
    "fiper_ros.nodes.rnd_oe_node": rnd_oe_node, "fiper_ros.nodes.ace_node": ace_node,
    "fiper_ros.nodes.detector_node": detector_node,
    "fiper_ros.nodes.fusion_node": fusion_node, "fiper_ros.nodes.supervisor_node": supervisor_node,
    "fiper_ros.nodes.policy_node": policy_node, "sim_bridge.bridge_node": bridge_node,
    "fiper_ros.nodes.view_node": view_node,
}


def node_grants(spec: NodeSpec) -> Grants:
    """What node ``spec`` does once ACTIVE, by absolute name."""
    rule = NODE_RULES.get(spec.module)
    if rule is None:
        raise UnknownNode(f"node {spec.fqn}: no grants known for module {spec.module} (write its enclave by hand)")
    try:
        return rule(effective_parameters(spec)).resolved(spec.fqn, spec.remaps)
    except (FiperError, OSError, ValueError) as error:
        raise LaunchError(f"node {spec.fqn}: {error}") from error


# the tools ---------------------------------------------------------------------------------------------------
def tool_grants() -> dict[str, Grants]:
    """The tools' own nodes (in the root namespace, by fully qualified name) and what each does: the recorders
    capture the bag schema's topics (their default) and read ``/diagnostics``; ``fiper echo`` may read the same;
    the demo's and the collect's operator also call ``/sim/reset`` (the demo records the cameras, ``/sim/*``
    and ``/clock`` too); ``fiper replay`` plays a bag's policy-side topics with ``/clock`` and reads the alarm."""
    from fiper_ros.client import live_collect, record, snapshot  # noqa: PLC0415 - rclpy and friends
    from fiper_ros.client.replay import NODE_NAME as REPLAY, played_topics  # noqa: PLC0415
    from fiper_ros.commands import demo, echo  # noqa: PLC0415

    recorded = Grants.of(subscribe=(*TOPICS, DIAGNOSTICS_TOPIC))
    operator = recorded | Grants.of(request=(SIM_RESET_SERVICE,))
    tools = {echo.NODE_NAME: recorded, record.NODE_NAME: recorded, snapshot.NODE_NAME: recorded,
             REPLAY: Grants.of(publish=(CLOCK_TOPIC, *played_topics(DETECTORS)), subscribe=(ALARM_TOPIC,)),
             demo.NODE_NAME: operator | Grants.of(subscribe=demo.EXTRA_TOPICS), live_collect.NODE_NAME: operator}
    return {f"/{name}": (ros_node({}) | grants).resolved(f"/{name}") for name, grants in tools.items()}


# the suites the project starts -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Deployment:
    """One suite the project starts: who starts it, and its launch configuration as started."""

    origin: str
    config: LaunchConfig


def nodes_policy(deployments: Iterable[Deployment]) -> dict[str, Grants]:
    """The union, per node, of what it does in each of ``deployments``."""
    policy: dict[str, Grants] = {}
    for deployment in deployments:
        for spec in deployment.config.nodes:
            policy[spec.enclave] = policy.get(spec.enclave, Grants()) | node_grants(spec)
    return policy


def shipped_policy() -> dict[str, Grants]:
    """The shipped policy: every node of :func:`shipped_deployments` and every tool."""
    return nodes_policy(shipped_deployments()) | tool_grants()


def share(package: str) -> Path:
    """The installed share directory of ``package``."""
    from ament_index_python.packages import get_package_share_directory  # noqa: PLC0415

    return Path(get_package_share_directory(package))


def shipped_launches() -> list[Path]:
    """The installed launch files of fiper_ros and sim_bridge (``launch/*.launch.yaml``; ``fiper.launch.py`` only
    includes its YAML)."""
    return sorted(p for name in ("fiper_ros", "sim_bridge") for p in (share(name) / "launch").glob("*.launch.yaml"))


def shipped_models() -> dict[Path, tuple[Path, ...]]:
    """The installed shipped models (``models/<task>/``) and each one's calibrations (its folders that hold a
    ``calibration.yaml``)."""
    models = sorted(p.parent for p in (share("fiper_ros") / "models").glob("*/policy.yaml"))
    return {m: tuple(sorted(c.parent for c in m.glob("*/calibration.yaml"))) for m in models}


def arm_for(calibration: Path) -> RobotModel | None:
    """The sim's arm (its URDF, EE frame ``panda_hand``) for a joint-space calibration, else None: what a
    Stacking deployment gives ACE (``urdf_path``; ``fiper replay --urdf``, ``fiper collect --ros``)."""
    from sim_bridge.robot import URDF_PATH  # noqa: PLC0415 - MuJoCo

    space = load_calibration(calibration).layout.action_space
    return None if space == ActionChunkBatch.ACTION_SPACE_EE_POSITION else RobotModel(str(URDF_PATH))


def shipped_deployments() -> Iterator[Deployment]:
    """Every suite the project starts with what it ships: each launch file (``fiper launch``) with its default
    arguments (and with the live view, where it declares ``view``), and on each shipped model and calibration (the arguments it declares of ``model``,
    ``calibration_dir`` and ``observation_only``, as ``fiper demo`` gives them; the sim's arm on ACE for a
    joint-space calibration, as ``fiper replay --urdf`` does: so ``fiper demo``'s suites are among them);
    ``fiper replay``'s suite for each calibration; ``fiper collect --ros``'s for each model, without and with
    each of its calibrations."""
    from fiper_ros.client.live_collect import LiveSettings, collect_config  # noqa: PLC0415
    from fiper_ros.client.suite_process import (SUITE_LAUNCH, detectors_of, installed_launch,  # noqa: PLC0415
                                                replay_launch, robot_parameters, suite_arguments)
    from fiper_ros.policy.config import PolicyConfig  # noqa: PLC0415

    models = shipped_models()
    pairs = [(model, calibration) for model, calibrations in models.items() for calibration in calibrations]
    for path in shipped_launches():
        config = load_launch(path)
        yield Deployment(f"fiper launch {path.name}", config)
        declared = {argument.name for argument in config.arguments}
        if "view" in declared:  # the live view as fiper demo runs it (any free port: building it serves), reading
            # every topic at once: on demand it reads only what a client shows, but may read any of them
            viewed = load_launch(path, {"view": "true", "view_port": "0"})
            yield Deployment(f"fiper launch {path.name} view:=true",
                             apply(viewed, Overrides(by_module={"fiper_ros.nodes.view_node": {"on_demand": False}})))
        variants = [config.nodes]
        for model, calibration in pairs:
            given = {"model": str(model), **suite_arguments(calibration, detectors_of(calibration))}
            on_model = load_launch(path, {k: v for k, v in given.items() if k in declared})
            variant = apply(on_model, Overrides(by_module=robot_parameters(arm_for(calibration))))
            if variant.nodes not in variants:  # a file without model or calibration arguments runs the same on all
                variants.append(variant.nodes)
                yield Deployment(f"fiper launch {path.name} on {_shown(calibration)}", variant)
    for _, calibration in pairs:
        yield Deployment(f"fiper replay --calibration {_shown(calibration)}",
                         replay_launch(installed_launch(SUITE_LAUNCH), calibration, detectors_of(calibration),
                                       arm_for(calibration)))
    for model, calibrations in models.items():
        task = PolicyConfig.read(model / "policy.yaml").task
        for calibration in (None, *calibrations):
            detectors = () if calibration is None else detectors_of(calibration)
            settings = LiveSettings(task, model, 0, 1, None, calibration, detectors)
            scored = "" if calibration is None else f" --calibration {_shown(calibration)}"
            yield Deployment(f"fiper collect --ros --task {task} --model {_shown(model)}{scored}",
                             collect_config(installed_launch("demo.launch.yaml"), settings))


def _shown(path: Path) -> str:
    """A shipped model's or calibration's path as the commands take it (``models/...``, found in the share)."""
    return str(path.relative_to(share("fiper_ros")))
