"""A name the core does not offer (a detector, a combine, a profile) is the user's error: a
:class:`~fiper_ros.core.errors.ChoiceError` (a ``CoreError``, no ``ValueError``) whose one line names what is offered;
the options of the commands that parse one are checked in test/evaluation/test_shared_options.py."""
from __future__ import annotations

from collections.abc import Callable

import pytest

from fiper_ros.core import CoreError
from fiper_ros.core.ace import check_alpha, check_binning
from fiper_ros.core.detectors import check_declared, check_once, check_pair_format, external_stream, info, signal_stream
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.fusion import Combine
from fiper_ros.core.profiles import get_profile


@pytest.mark.parametrize(("refuse", "message"), [
    (lambda: info("sonar"), "unknown detector 'sonar'; expected one of rnd_oe, ace, logpzo, pca_kmeans, rnd_a, stac, "
                            "progress, consistency, elapsed, signal_<name> or external_<name>"),
    (lambda: info("signal_Bad"), "unknown detector 'signal_Bad'; expected one of "),
    (lambda: check_declared("stac"), "detector 'stac' cannot be calibrated (an evaluation baseline); declare some of "
                                     "rnd_oe, ace, logpzo, pca_kmeans, progress, consistency, elapsed or signal_<name>"),
    (lambda: check_declared("sonar"), "unknown detector 'sonar'; "),
    (lambda: Combine.parse("xor"), "unknown combine 'xor'; expected one of and, or, max, kth:K"),
    (lambda: Combine.parse("kth:0"), "combine 'kth:0': kth:K needs an integer K >= 1 (e.g. kth:2)"),
    (lambda: Combine.parse("max:2"), "combine 'max:2': only kth takes a count (kth:K)"),
    (lambda: Combine("and", 2), "and takes no K"),
    (lambda: get_profile("fast"), "unknown profile 'fast'; expected one of ('paper', 'reference')"),
    (lambda: Combine.parse("kth:3").votes(2), "combine kth:3 needs at least 3 detectors, got 2"),
    (lambda: signal_stream("Grip"), "signal name 'Grip' must match [a-z][a-z0-9_]* (it becomes a topic and a stream "
                                    "name)"),
    (lambda: signal_stream("grip\n"), "signal name 'grip\\n' must match"),
    (lambda: external_stream("my-model"), "external score name 'my-model' must match [a-z][a-z0-9_]* (it becomes the "
                                          "stream external_<name>)"),
    (lambda: check_once(("rnd_oe", "rnd_oe")), "declare each detector once, at least one, got rnd_oe,rnd_oe"),
    (lambda: check_once(()), "declare each detector once, at least one, got (none)"),
    (lambda: check_pair_format(("ace",)), "unsupported detectors ace: declare rnd_oe,ace or rnd_oe"),
    (lambda: check_binning("float32"), "unknown ACE binning 'float32'; expected one of "),
])
def test_an_unknown_choice_is_a_core_error_in_one_line(refuse: Callable[[], object], message: str) -> None:
    with pytest.raises(ChoiceError) as raised:
        refuse()
    assert isinstance(raised.value, CoreError) and not isinstance(raised.value, ValueError)
    assert str(raised.value).startswith(message) and "\n" not in str(raised.value)



def test_a_cell_size_factor_outside_the_unit_interval_is_a_core_error() -> None:
    with pytest.raises(CoreError) as raised:
        check_alpha(1.5)
    assert str(raised.value) == "cell size factor alpha must be in (0, 1), got 1.5"
    assert not isinstance(raised.value, ValueError)
