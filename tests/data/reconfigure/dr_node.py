"""Debian's dynamic_reconfigure (rospy) for the interop tests; answers as JSON lines.

dr_node.py server                 dynamic_reconfigure's own TestConfig server as /dr_server; prints "up"
dr_node.py get NODE               prints the client's get_configuration() (parameters only) as JSON
dr_node.py set NODE JSON          update_configuration(JSON); prints the returned config as JSON
"""

import json
import sys

import rospy
from dynamic_reconfigure.client import Client


def params(config):
    return {k: v for k, v in config.items() if k != "groups"}


if sys.argv[1] == "server":
    from dynamic_reconfigure.cfg import TestConfig
    from dynamic_reconfigure.server import Server

    rospy.init_node("dr_server")
    Server(TestConfig, lambda config, level: config)
    print("up", flush=True)
    rospy.spin()
else:
    rospy.init_node("dr_client", anonymous=True)
    client = Client(sys.argv[2], timeout=20)
    if sys.argv[1] == "get":
        print(json.dumps(params(client.get_configuration(timeout=20))), flush=True)
    else:
        print(json.dumps(params(client.update_configuration(json.loads(sys.argv[3])))), flush=True)
