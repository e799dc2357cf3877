"""The registry of force terms beyond the linear core (server/force_term.py): each scene gets the
terms it uses, built in this order, which is also the order their reply fields are added to the
load (protocol/reply.py lists the fields in the same order)."""

from __future__ import annotations

from hydrolink.server.force_term import ForceTerm, TermContext
from hydrolink.server.morison import MorisonTerm
from hydrolink.server.nonlinear_hydro import NonlinearTerm
from hydrolink.server.second_order import SecondOrderTerm
from hydrolink.server.viscous import ViscousTerm

#: every force term the server knows, in reply order
TERMS: tuple[type[ForceTerm], ...] = (ViscousTerm, MorisonTerm, NonlinearTerm, SecondOrderTerm)


def build_terms(ctx: TermContext, registry: tuple[type[ForceTerm], ...] = TERMS) -> list[ForceTerm]:
    """The terms the scene of ``ctx`` uses (each term's build returns None when it has none)."""
    return [term for cls in registry if (term := cls.build(ctx)) is not None]
