"""``planar-vo batch``: a fleet's logs run as one Ray task per log, resumable, one summary.

Layers: :mod:`.logs` finds the logs, names their result folders and hashes their content;
:mod:`.task` runs one log with ``planar-vo run``'s code path (no Ray in it); :mod:`.runner`
schedules the tasks on Ray (local or a cluster) and decides what to skip; :mod:`.summary`
writes ``summary.csv``, ``summary.json`` and ``summary.md``.
"""
