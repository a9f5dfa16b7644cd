"""Which analyzers of a diagnostic_aggregator analyzer YAML match a status name, by GenericAnalyzer's rules
(ros/diagnostics diagnostic_aggregator/src/generic_analyzer.cpp ``match``: a full ``regex`` match, an exact
``expected`` or ``name``, a ``startswith`` prefix, a ``contains`` substring); AnalyzerGroups are walked."""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import yaml

CONFIG = Path(os.environ["FIPER_ROOT"]) / "fiper_ros" / "config" / "diagnostics_aggregator.yaml"
GENERIC = "diagnostic_aggregator/GenericAnalyzer"
GROUP = "diagnostic_aggregator/AnalyzerGroup"


def generic_analyzers(config: Path = CONFIG) -> dict[str, dict[str, Any]]:
    """Every GenericAnalyzer of ``config`` by its output path (``/FIPER/Detectors``)."""
    found: dict[str, dict[str, Any]] = {}

    def walk(analyzers: dict[str, Any], base: str) -> None:
        for spec in analyzers.values():
            if not isinstance(spec, dict):
                continue  # a parameter of the aggregator (path, pub_rate), not an analyzer
            path = f"{base}/{spec['path']}"
            if spec["type"] == GROUP:
                walk(spec["analyzers"], path)
            else:
                assert spec["type"] == GENERIC, spec
                found[path] = spec

    walk(yaml.safe_load(config.read_text())["analyzers"]["ros__parameters"], "")
    return found


def matches(spec: dict[str, Any], name: str) -> bool:
    """GenericAnalyzer::match."""
    return (any(re.fullmatch(p, name) for p in spec.get("regex", []))
            or name in spec.get("expected", []) or name in spec.get("name", [])
            or any(name.startswith(p) for p in spec.get("startswith", []))
            or any(p in name for p in spec.get("contains", [])))


def analyzers_of(name: str, config: Path = CONFIG) -> list[str]:
    """The output paths of the analyzers that match the status ``name``."""
    return [path for path, spec in generic_analyzers(config).items() if matches(spec, name)]
