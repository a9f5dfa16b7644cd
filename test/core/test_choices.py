"""A name the core does not offer (a detector, a combine, a profile) is the user's error: a
:class:`~fiper_ros.core.errors.ChoiceError` (a ``CoreError``, no ``ValueError``) whose one line names what is offered;
the options of the commands that parse one are checked in test/evaluation/test_shared_options.py."""
from __future__ import annotations

from collections.abc import Callable

import pytest

from fiper_ros.core import CoreError
from fiper_ros.core.detectors import check_declared, info
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
])
def test_an_unknown_choice_is_a_core_error_in_one_line(refuse: Callable[[], object], message: str) -> None:
    with pytest.raises(ChoiceError) as raised:
        refuse()
    assert isinstance(raised.value, CoreError) and not isinstance(raised.value, ValueError)
    assert str(raised.value).startswith(message) and "\n" not in str(raised.value)

