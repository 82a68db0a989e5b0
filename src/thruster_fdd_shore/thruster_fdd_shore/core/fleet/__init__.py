"""Fleet health over a recording archive, on Dask (docs/fleet.md): scan every recording of every
vehicle with the vehicle's own residual, decision and effectiveness code into a Parquet dataset,
then report, compare model pairs and pick healthy stretches for retraining. ROS-free."""
