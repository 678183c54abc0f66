"""The state of a running recorder, for people and scripts: snapshots read from the log
it writes (:mod:`acq.monitor.log_source`; a live server is another source of the same
:class:`acq.monitor.snapshot.Snapshot`), their problems, a terminal view."""
