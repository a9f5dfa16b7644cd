"""The seven evaluated methods and the per-step score streams they read (Table 1 of the paper).

A *stream* is one per-step score per rollout step (``s_RND``, ``s_ACE`` or a baseline's score). Every
method but FIPER thresholds one stream; FIPER fuses the RND-OE and ACE streams with AND/OR (eq. 7).
:class:`MethodSettings` holds every hyperparameter that changes a stream, so it is part of the
score-cache key.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from fiper_ros.baselines.logpzo import LogpZOConfig
from fiper_ros.baselines.pca_kmeans import PCAKMeansConfig
from fiper_ros.baselines.rnd_a import RNDAConfig
from fiper_ros.core.compat import get_profile
from fiper_ros.core.kinematics import RobotModel
from fiper_ros.core.rnd_oe import RNDConfig


@dataclass(frozen=True)
class Method:
    """Display name and the streams a method reads."""

    label: str
    streams: tuple[str, ...]


#: Methods in the column order of Table 1.
METHODS: dict[str, Method] = {
    "pca_kmeans": Method("PCA-kmeans", ("pca_kmeans",)),
    "logpzo": Method("logpZO", ("logpzo",)),
    "rnd_a": Method("RND-A", ("rnd_a",)),
    "stac": Method("STAC", ("stac",)),
    "rnd_oe": Method("RND-OE", ("rnd_oe",)),
    "ace": Method("ACE", ("ace",)),
    "fiper": Method("FIPER", ("rnd_oe", "ace")),
}

#: Streams whose scores do not depend on the seed (no training, no random split).
SEEDLESS_STREAMS = frozenset({"stac", "ace"})

#: Evaluation default for RND-OE: the core's small network with a CPU training budget
#: (lr 1e-3, at most 50 epochs, early stopping as in the paper).
EVAL_RND = RNDConfig(max_epochs=50, lr=1e-3)


@dataclass(frozen=True)
class MethodSettings:
    """Hyperparameters of every stream.

    Attributes:
        profile: ``"paper"`` or ``"reference"`` (:mod:`fiper_ros.core.compat`): ACE/RND-OE score
            details, threshold details and the DT normalisation.
        alpha: ACE cell size factor; ``None`` uses the profile's.
        rnd: RND-OE network and training.
        pca_kmeans, logpzo, rnd_a: The baselines' configurations.
        robot: FK and control period for ACE on joint-space actions (App. A.1); ``None`` for
            end-effector actions.
    """

    profile: str = "paper"
    alpha: float | None = None
    rnd: RNDConfig = EVAL_RND
    pca_kmeans: PCAKMeansConfig = field(default_factory=PCAKMeansConfig)
    logpzo: LogpZOConfig = field(default_factory=LogpZOConfig)
    rnd_a: RNDAConfig = field(default_factory=RNDAConfig)
    robot: RobotModel | None = None

    def __post_init__(self) -> None:
        get_profile(self.profile)

    @classmethod
    def tiny(cls, profile: str = "paper") -> MethodSettings:
        """Very small networks and budgets, for tests and smoke runs (numbers are not meaningful)."""
        tiny_rnd = RNDConfig(trunk=(32, 32), head=(32,), out_dim=16, max_epochs=8, lr=1e-3)
        return cls(
            profile=profile,
            rnd=tiny_rnd,
            pca_kmeans=PCAKMeansConfig(components=8, clusters=16),
            logpzo=LogpZOConfig(hidden=(32, 32), epochs=8),
            rnd_a=RNDAConfig(channels=8, train_samples=2, score_samples=8, rnd=tiny_rnd),
        )

    def stream_settings(self, stream: str, joint_space: bool = False) -> dict[str, Any]:
        """The settings that determine ``stream`` (plain data, for the cache key); the robot model
        only for ACE on a task with ``joint_space`` actions."""
        common: dict[str, Any] = {"profile": self.profile}
        if stream == "rnd_oe":
            return {**common, "rnd": self.rnd.to_dict()}
        if stream == "ace":
            robot = {"robot": self.robot.to_dict()} if joint_space and self.robot is not None else {}
            return {**common, "alpha": self.alpha, **robot}
        if stream == "stac":
            return common
        if stream == "pca_kmeans":
            return {**common, **asdict(self.pca_kmeans)}
        if stream == "logpzo":
            return {**common, **self.logpzo.to_dict()}
        if stream == "rnd_a":
            return {**common, **self.rnd_a.to_dict()}
        raise ValueError(f"unknown stream {stream!r}")


def streams_of(methods: list[str]) -> list[str]:
    """The distinct streams the methods read, in first-use order."""
    out: list[str] = []
    for name in methods:
        if name not in METHODS:
            raise ValueError(f"unknown method {name!r}; expected some of {list(METHODS)}")
        out.extend(s for s in METHODS[name].streams if s not in out)
    return out
