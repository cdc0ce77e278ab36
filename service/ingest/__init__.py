"""The ingest's stages, each testable alone (issue 38): learning the first noise floor
(:mod:`~service.ingest.learn`), the still and hull detectors (:mod:`~service.ingest.still`,
:mod:`~service.ingest.hull`) with the stored noise floor (:mod:`~service.ingest.floor_keeper`),
the rest check (:mod:`~service.ingest.rest_check`), the underway rule
(:mod:`~service.ingest.underway`) and the store (:mod:`~service.ingest.store`: spool, database,
events). :class:`service.pipeline.Ingest` runs them in order; :mod:`~service.ingest.setup`
builds their configuration from the settings and :mod:`~service.ingest.thread` runs the ingest
in a thread of its own."""
