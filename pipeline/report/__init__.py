"""The study's report: HTML report, recorded-study sections, tables, findings (application side).

=================  ==============================================================
module             what it holds
=================  ==============================================================
``html``           :func:`~pipeline.report.html.write_report`: the run's report.html
``recorded``       the report's sections for a recorded study (sim vs real, calibration)
``tables``         the report's tables from the evaluation's JSON
``findings``       the findings a report states, each with its interval
``smokescale``     whether a run's settings are smoke-scale (banner on figures and report)
=================  ==============================================================
"""
