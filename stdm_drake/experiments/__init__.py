"""Experiments built from the stages above: the paper's reproduction and the sine-sum study, and
the report writer they share."""
