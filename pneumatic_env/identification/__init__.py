"""Identification from recordings: calibration, residual diagnosis, report, virtual rig.

See docs/identification.md. Command line: ``pneumatic-env identify runs/*.csv --report
report/`` (:mod:`.cli`) and ``pneumatic-env rig --effect NAME --strength S --out DIR``
(:mod:`.virtual_rig`). Python API (modules are imported on use):

- :func:`.calibrate.calibrate` -> :class:`.calibrate.Calibration` (``.result``, ``.save``)
- :func:`.diagnose.diagnose` -> :class:`.diagnose.Diagnosis` (``.to_json()``)
- :func:`.report.write_report`
- :func:`.candidates.available_candidates`, :func:`.candidates.apply_sensor_model`
- :func:`.checks.read_checked`, :func:`.checks.check_recordings`
- :func:`.virtual_rig.run_rig`, :func:`.virtual_rig.make_recording`
- ``python -m pneumatic_env.studies.identification_eval``: confusion matrix on the virtual rig

Settings: ``configs/identification.yaml`` (:func:`.config.load_config`).
"""
