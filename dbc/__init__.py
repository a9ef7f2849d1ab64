"""DBC-driven applications: ECUs and rest-bus simulation built from a database (cantools).

Sample databases live in ``dbc/databases/``. Imports `profiles` and `stack`.
"""
