"""The paper's protocol over the stages: its plan (which runs, which seeds, which
selections), the driver that runs that plan on local workers or Ray, the pre-registration
gate, the live view and status, batches for machines elsewhere, and the archive of a
finished protocol. It calls :mod:`pved.experiments`' stages; the stages know nothing of it."""
