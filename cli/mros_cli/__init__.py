"""`mros`: the command-line tool for ROS users (topics, messages, parameters, nodes, IXM)."""
