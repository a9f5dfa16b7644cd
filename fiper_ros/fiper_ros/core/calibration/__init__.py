"""Calibration: everything FIPER fits from successful ID rollouts (Sec. 4, App. A), and its file.

- :mod:`.settings`: what a calibration is fitted with (:class:`CalibrationSettings`).
- :mod:`.model`: a fitted calibration (:class:`Calibration`: per task, each detector's scorer and threshold) and
  what it promises (:func:`guarantee`).
- :mod:`.fit`: the split of the successes and the fit (:func:`calibrate`).
- :mod:`.auto`: ``--auto``: the fold scores and failure proxies the choice rests on (the ``transfer`` rule: a
  prior's entry the successes can feed, :func:`~.auto.transfer_choice`), and the calibration of the chosen
  configuration (:func:`auto_calibrate`).
- :mod:`.store`: reading ``calibration.yaml`` and the models' files (:func:`load_calibration`); a calibration
  writes itself (:meth:`Calibration.save`).

Loading a calibration and scoring with it needs numpy, not torch; fitting imports torch for RND-OE's and logpZO's
training.
"""
from __future__ import annotations

from fiper_ros.core.calibration.auto import auto_calibrate, choose_configuration
from fiper_ros.core.calibration.fit import CalibrationSplit, calibrate, false_alarm_estimate, split_successes
from fiper_ros.core.calibration.model import (Calibration, CalibrationMismatch, DetectorPart, Layout, TaskPart,
                                              guarantee, promised_rate)
from fiper_ros.core.calibration.settings import SPLITS, CalibrationSettings
from fiper_ros.core.calibration.store import load_calibration, upgrade_calibration
from fiper_ros.core.calibration_file import CalibrationError

__all__ = ["SPLITS", "Calibration", "CalibrationError", "CalibrationMismatch", "CalibrationSettings",
           "CalibrationSplit", "DetectorPart", "Layout", "TaskPart", "auto", "auto_calibrate", "calibrate",
           "choose_configuration", "false_alarm_estimate", "fit",
           "guarantee", "load_calibration", "model", "promised_rate", "settings",
           "split_successes", "store", "upgrade_calibration"]
