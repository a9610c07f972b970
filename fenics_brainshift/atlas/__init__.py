"""Model-updated guidance: an atlas of settled states computed before surgery
(``brainshift atlas``), and the combination of them that fits what is measured once the dura
is open (``brainshift update``). docs/update.md shows the workflow."""
