"""Reporting: JUnit XML, the HTML report and its plots."""
