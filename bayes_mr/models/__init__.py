"""Model forms, effects and their composition (see ``docs/CONTRACT.md``, Models/Effects)."""

from .effects import (
    ASYMMETRY,
    CUBIC_STIFFNESS,
    EFFECTS,
    FORCE_OFFSET,
    LOW_VELOCITY_ROLLOFF,
    NONE,
    SENSOR_DELAY,
    SMALL_AMPLITUDE_REGIME,
    STIFFNESS_DRIFT,
    VOLTAGE_DEPENDENCE,
    Effect,
)
from .forms import BOUC_WEN, DAHL, FORMS, LUGRE, NORMALIZED_BOUC_WEN, SPENCER, Form
from .model import KINDS, Model, get_model
from .params import Coordinates, ParamSpec, Scales

__all__ = [
    "ASYMMETRY", "BOUC_WEN", "CUBIC_STIFFNESS", "Coordinates", "DAHL", "EFFECTS", "Effect",
    "FORCE_OFFSET", "FORMS", "Form", "KINDS", "LOW_VELOCITY_ROLLOFF", "LUGRE", "Model", "NONE",
    "NORMALIZED_BOUC_WEN", "ParamSpec", "SENSOR_DELAY", "SMALL_AMPLITUDE_REGIME", "SPENCER",
    "STIFFNESS_DRIFT", "Scales", "VOLTAGE_DEPENDENCE", "get_model",
]
