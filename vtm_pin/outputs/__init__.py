"""What a run produces.

Energies and momenta (``analysis``), the stopping report (``stopping``), the signed
figures and their table columns (``figures``: a new output column goes here), the flags of
broken assumptions (``flags``), the summary (``report``), plots and drawings, and a
scenario run end to end as a library call (``pipeline``).

May import: scene and everything below it.
"""
