"""The statistics and the figures and reports of finished runs: every module reads run
records and computes; none rolls out an env or runs a stage (that is
:mod:`pved.diagnostics`), so a verdict can be redrawn from committed records alone."""
