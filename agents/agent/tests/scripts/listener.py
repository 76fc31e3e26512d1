#!/usr/bin/python3
"""rospy listener for the runtime tests: one "msg" line per message, flushed.
usage: listener.py NODE TOPIC"""
import sys

import rospy
from std_msgs.msg import String

name, topic = sys.argv[1], sys.argv[2]
rospy.init_node(name, anonymous=False, disable_signals=True)


def cb(_msg):
    sys.stdout.write("msg\n")
    sys.stdout.flush()


rospy.Subscriber(topic, String, cb, queue_size=100, tcp_nodelay=True)
sys.stdout.write("ready\n")
sys.stdout.flush()
rospy.spin()
