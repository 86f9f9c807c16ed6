"""The exemplar styles of the paper (section 2): what an exemplar record holds.

Every style's exemplar is a record with some of four fields, held by ``ExemplarPolicy`` as
arrays with one row per exemplar:

==========  ============  =====================================================================
field       array         meaning
==========  ============  =====================================================================
state       (L, D) float  s_j: the exemplar's state (state-state: s1_j, the better state)
state2      (L, D) float  s2_j of state-state: the worse state of the pair
action      (L,) int      a_j: an index into the problem's actions
value       (L,) float    v_j: a value (an episode return) of the state or state-action
==========  ============  =====================================================================

A style names the fields it uses, how they are written in a policy file (``keys``), and the
number by which the compiled selector (``sapga_ros.exemplars.selectors.select``) knows it.
The SAP-GA operators act on whole records, whatever they hold.  Adding a style: one entry
here and one branch in ``selectors.select`` (docs/architecture.md).
"""
from __future__ import annotations

from dataclasses import dataclass

from sapga_ros.errors import SapgaError

FIELDS = ('state', 'state2', 'action', 'value')


@dataclass(frozen=True)
class Style:
    """One exemplar style: its selector number, record fields and file keys."""

    name: str
    number: int                    # the selector's branch in ``selectors.select``
    keys: dict                     # record field -> JSON key of an exemplar in a policy file
    summary: str                   # one line for --help and the docs

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(self.keys)

    def uses(self, name: str) -> bool:
        return name in self.keys


STATE_ACTION, VIA_POINT, STATE_VALUE, STATE_STATE, STATE_ACTION_VALUE = range(5)

STYLES: dict[str, Style] = {s.name: s for s in (
    Style('state-action', STATE_ACTION, {'state': 'state', 'action': 'action'},
          'exemplars (s_j, a_j); the nearest exemplar\'s action'),
    Style('via-point', VIA_POINT, {'state': 'state'},
          'an ordered list of states; the action whose next state is nearest to the first '
          'via-point not yet reached (then the best state)'),
    Style('state-value', STATE_VALUE, {'state': 'state', 'value': 'value'},
          'exemplars (s_j, v_j); the action whose next state has the best nearest-exemplar '
          'value'),
    Style('state-state', STATE_STATE, {'state': 'better', 'state2': 'worse'},
          'pairs "s1 is better than s2"; the action whose next state is nearer to a better '
          'state than to any worse one, by the widest margin'),
    Style('state-action-value', STATE_ACTION_VALUE,
          {'state': 'state', 'action': 'action', 'value': 'value'},
          'exemplars (s_j, a_j, v_j); the action whose nearest exemplar with that action '
          'has the best value'),
)}


def style_named(name: str) -> Style:
    """The style called ``name``; unknown names are a one-line error listing the known."""
    try:
        return STYLES[name]
    except (KeyError, TypeError):
        raise SapgaError(f'unknown exemplar style {str(name)[:40]!r} '
                         f'(known: {", ".join(STYLES)})') from None
