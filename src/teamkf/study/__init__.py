"""The study layer: what turns files and names into objects and rows.

Scenario, population and sweep files (:mod:`~teamkf.study.scenario`,
:mod:`~teamkf.study.population`, :mod:`~teamkf.study.sweep`), one scenario's
costs as rows (:func:`~teamkf.study.evaluate.evaluate_point`), sweep results
(:mod:`~teamkf.study.results`) and instance builders such as the Section VII
random field (:mod:`~teamkf.study.random_field`). Engines (sampling, Monte
Carlo, the runtime, the Dask client) live in :mod:`teamkf.simulation`; the
estimator families in :mod:`teamkf.estimators`.
"""
