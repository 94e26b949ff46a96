"""Model forms, effects and their composition (see ``docs/CONTRACT.md``, Models/Effects)."""

from bayes_mr.models.registry import get_model
from bayes_mr.models.effects import (
    ASYMMETRY, COMMAND_POLYNOMIAL, COMMAND_SATURATION, CUBIC_STIFFNESS, EFFECTS, EXPONENTIAL_SATURATION, FIELD_DECAY, FIELD_DYNAMICS, FORCE_OFFSET, INERTIA,
    LOW_VELOCITY_ROLLOFF, NONE, SENSOR_DELAY, SHEAR_THINNING, SMALL_AMPLITUDE_REGIME, STIFFNESS_DRIFT,
    STRIBECK_FRICTION, VOLTAGE_DEPENDENCE, Effect,
)
from bayes_mr.models.forms import BOUC_WEN, DAHL, FORMS, LUGRE, NORMALIZED_BOUC_WEN, SPENCER
from bayes_mr.models.model import KINDS, Form, Model
from bayes_mr.models.params import Coordinates, ParamSpec, Scales

__all__ = [
    "ASYMMETRY", "BOUC_WEN", "COMMAND_POLYNOMIAL", "COMMAND_SATURATION", "CUBIC_STIFFNESS", "Coordinates", "DAHL",
    "EFFECTS", "EXPONENTIAL_SATURATION", "Effect",
    "FIELD_DECAY", "FIELD_DYNAMICS", "FORCE_OFFSET", "FORMS", "Form", "INERTIA", "KINDS", "LOW_VELOCITY_ROLLOFF", "LUGRE", "Model",
    "NONE", "NORMALIZED_BOUC_WEN", "ParamSpec", "SENSOR_DELAY", "SHEAR_THINNING", "SMALL_AMPLITUDE_REGIME", "SPENCER",
    "STIFFNESS_DRIFT", "STRIBECK_FRICTION", "Scales", "VOLTAGE_DEPENDENCE", "get_model",
]
