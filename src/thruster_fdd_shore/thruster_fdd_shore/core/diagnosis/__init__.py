"""Training and evaluation of the classifier (the paper's Table 3), offline diagnosis of a trace
with the vehicle's own stream code."""
