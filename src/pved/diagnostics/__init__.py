"""Diagnostics: the analyses that run something again (roll out a policy in its env,
refit a model, collect pairs) to explain a finished protocol's numbers, where
:mod:`pved.analysis` only reads records and computes. They may import the experiments'
stages; nothing below them imports them."""
