"""Scenario specs (YAML), their validation, the named scenario library and suites."""
