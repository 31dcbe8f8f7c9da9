"""The input-name check every built-in simulator calls: one message for all of them."""

from __future__ import annotations

import pytest

from calnet.simulators import melt_pool, phase_field, solidification
from calnet.simulators.base import check_input_names


def test_unknown_and_missing_names_are_refused_with_the_fix():
    args = ("sim", ("P", "v"), ("k",), {"P": "W", "v": "m/s"})
    check_input_names(args[0], {"P": 1.0, "v": 2.0}, *args[1:])
    check_input_names(args[0], {"P": 1.0, "v": 2.0, "k": 3.0}, *args[1:])
    with pytest.raises(ValueError, match=r"^sim: unknown inputs \['kk'\]; expected \['P', "
                                         r"'v'\] and optionally \['k'\]$"):
        check_input_names(args[0], {"P": 1.0, "kk": 3.0}, *args[1:])  # unknown named first
    with pytest.raises(ValueError, match=r"^sim: missing control inputs \['v'\]; pass P \(W\), "
                                         r"v \(m/s\), got \['P'\]$"):
        check_input_names(args[0], {"P": 1.0}, *args[1:])


@pytest.mark.parametrize("module", [melt_pool, phase_field, solidification])
def test_every_builtin_uses_the_check(module):
    good = {k: 0.5 * sum(module.BOUNDS[k]) for k in module.INPUTS}
    with pytest.raises(ValueError, match=rf"^{module.NAME}: unknown inputs \['typo'\]"):
        module.simulate({**good, "typo": 1.0})
    with pytest.raises(ValueError, match=rf"^{module.NAME}: missing control inputs "
                                         rf"\['{module.INPUTS[-1]}'\]"):
        module.simulate({module.INPUTS[0]: good[module.INPUTS[0]]})
