"""Names of the logged inverse-model accuracies, one meaning per column.

* ``idm_accuracy`` (:data:`IDM_ACCURACY_AGENT`): the inverse-dynamics loss's own
  diagnostic, ``argmax P_i == a`` on the agent's own batch, measured before the
  update that trains on it; no expert label is read.
* ``idm_accuracy_expert`` (:data:`IDM_ACCURACY_EXPERT`): the inferred label equals
  the expert's true action on the demo pairs; the true actions are read for this
  diagnostic only. NaN where the demos carry no actions.

Files written before the two were named apart (all results this project committed
before December 2026) have one ``idm_accuracy`` column that held the expert-pair
accuracy, since their demos carried labels; :func:`upgrade_accuracy_keys` reads them so.
"""

from __future__ import annotations

__all__ = ["IDM_ACCURACY_AGENT", "IDM_ACCURACY_EXPERT", "upgrade_accuracy_keys"]

IDM_ACCURACY_AGENT = "idm_accuracy"
IDM_ACCURACY_EXPERT = "idm_accuracy_expert"


def upgrade_accuracy_keys(record: dict) -> dict:
    """A row or summary read from a file written before the rename, with its
    ``idm_accuracy`` moved to ``idm_accuracy_expert`` (in place; newer records, which
    always carry ``idm_accuracy_expert`` where an inverse model exists, are unchanged)."""
    if IDM_ACCURACY_EXPERT not in record and IDM_ACCURACY_AGENT in record:
        record[IDM_ACCURACY_EXPERT] = record.pop(IDM_ACCURACY_AGENT)
    return record
