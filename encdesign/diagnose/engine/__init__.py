"""The finder's engine: the stages every recording kind goes through (prepare, fit, views,
select, evidence, steps, noise, nuisances, document, engine), the kind protocol
(:class:`~encdesign.diagnose.engine._kind.AbstractKind`), the settings, the candidate
registration API, the typed results and the plots and HTML report. Imports no kind."""
