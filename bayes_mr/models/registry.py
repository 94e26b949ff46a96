"""Model names: ``FORM[+EFFECT...]`` → :class:`~bayes_mr.models.model.Model`.

The names are those of ``docs/CONTRACT.md`` (Models, Effects): the five forms
of :data:`bayes_mr.models.forms.FORMS` and the effects of
:data:`bayes_mr.models.effects.EFFECTS`.
"""

from __future__ import annotations

from bayes_mr.models.effects import EFFECTS, NONE
from bayes_mr.models.forms import FORMS
from bayes_mr.models.model import Model
from bayes_mr.models.terms import is_term, make


def get_model(name: str | Model) -> Model:
    """Parse ``FORM[+EFFECT...]`` (e.g. ``"spencer+force_offset+sensor_delay"``).

    An effect may also be a library term, ``term(EXPR)`` or ``zterm(EXPR)``
    (:mod:`bayes_mr.models.terms`), e.g. ``"spencer+term(u*abs(xdot))"``.

    Parameters
    ----------
    name : str or Model
        A model name; a :class:`Model` is returned unchanged. ``+none`` is
        accepted and ignored.

    Returns
    -------
    Model

    Raises
    ------
    ValueError
        Unknown form or effect (the message lists the valid names).
    """
    if isinstance(name, Model):
        return name
    parts = [p.strip() for p in str(name).split("+") if p.strip()]
    if not parts or parts[0] not in FORMS:
        head = parts[0] if parts else ""
        raise ValueError(f"unknown model form '{head}'; valid: {', '.join(FORMS)}")
    model = Model(FORMS[parts[0]])
    for p in parts[1:]:
        if p == NONE:
            continue
        if is_term(p):
            model = model + make(p, model.form.name)
            continue
        if p not in EFFECTS:
            raise ValueError(f"unknown effect '{p}'; valid: {', '.join(EFFECTS)}")
        model = model + EFFECTS[p]
    return model
