"""The registry of force terms beyond the linear core (server/terms/base.py): each scene gets the
terms it uses, built in this order, which is also the order their reply fields are added to the
load (protocol/reply.py lists the fields in the same order)."""

from __future__ import annotations

from hydrolink.server.terms.base import ForceTerm, TermContext
from hydrolink.server.terms.morison import MorisonTerm
from hydrolink.server.terms.nonlinear.term import NonlinearTerm
from hydrolink.server.terms.second_order import SecondOrderTerm
from hydrolink.server.terms.viscous import ViscousTerm

#: every force term the server knows, in reply order
TERMS: tuple[type[ForceTerm], ...] = (ViscousTerm, MorisonTerm, NonlinearTerm, SecondOrderTerm)


def build_terms(ctx: TermContext, registry: tuple[type[ForceTerm], ...] = TERMS) -> list[ForceTerm]:
    """The terms the scene of ``ctx`` uses (each term's build returns None when it has none)."""
    return [term for cls in registry if (term := cls.build(ctx)) is not None]
