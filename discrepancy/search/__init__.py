"""Search-and-fit stage: screening and refining catalogue candidates, greedy naming, the joint fit, the budget."""
