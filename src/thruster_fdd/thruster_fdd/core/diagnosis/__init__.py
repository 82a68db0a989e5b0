"""The fault classifier and thruster health on the vehicle (docs/diagnosis.md).

``features`` (window features), ``model`` (the loaded classifier), ``stream`` (online
decisions), ``reference`` (the exported reference load curves), ``effectiveness`` (thrust
available) and ``health`` (vehicle-level health).
"""
