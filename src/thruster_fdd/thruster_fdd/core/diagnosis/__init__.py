"""The fault classifier: residual windows in, the diagnosed condition out (docs/diagnosis.md).

On the vehicle: ``features`` (window features), ``model`` (the loaded classifier), ``stream``
(online decisions). On shore: ``offline`` (a whole trace), ``training``, ``metrics``,
``evaluation`` and ``table3`` (the paper's protocol).
"""
