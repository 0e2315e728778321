"""Benchmarks: each module measures one part against real ROS in the same run and prints ratios."""
