"""odolab/odometry/configured.py: an odometer that declares its ``Config`` takes keyword options for
its fields (nested ones too), lists them in its signature, and is checked by them."""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import pytest

from odolab import api
from odolab.odometry.configured import OptionTypeError, config_digest


@dataclass(frozen=True)
class Inner:
    gain: float = api.setting(1.0, range=(0.0, 10.0), doc="a gain")

    def __post_init__(self) -> None:
        api.check(self)


@dataclass(frozen=True)
class Options:
    steps: int = api.setting(3, range=(1, 100), doc="steps")
    inner: Inner = Inner()

    def __post_init__(self) -> None:
        api.check(self)


class Configured(api.Odometer):
    Config = Options

    def __init__(self, config: Options | None = None, **overrides) -> None:
        self.config = api.configure(Options, config, **overrides)
        self.identity_digest = config_digest(self.config)

    def step(self, prev, cur, action):
        return api.Estimate.invalid()


def test_a_declared_config_gives_the_options_their_signature_and_checks():
    assert list(inspect.signature(Configured).parameters) == ["config", "steps", "inner", "gain"]
    odo = Configured(gain=2.5, steps=4)
    assert odo.config == Options(steps=4, inner=Inner(gain=2.5))
    assert odo.identity_digest == Configured(steps=4, gain=2.5).identity_digest != Configured().identity_digest
    with pytest.raises(TypeError, match="has no option 'gian'"):
        Configured(gian=2.0)
    with pytest.raises(OptionTypeError, match="steps must be int, got 'x'"):  # a TypeError and a ValueError
        Configured(steps="x")
    with pytest.raises(ValueError, match=r"gain must be in \[0, 10\], got 11"):
        Configured(gain=11.0)


def test_the_registry_checks_a_plug_ins_options_by_its_fields():
    from odolab.odometry.options import OptionError, check_options

    check_options("configured-test", Configured, {"gain": 3.0})
    with pytest.raises(OptionError, match="has no option 'gian'.*did you mean 'gain'"):
        check_options("configured-test", Configured, {"gian": 3.0})
    assert api.load_odometer("tests.test_configured:Configured", gain=3.0).config.inner.gain == 3.0  # by module:Class
