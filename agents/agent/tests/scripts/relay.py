#!/usr/bin/python3
"""rospy relay for the runtime tests: republishes every message of IN on
OUT. usage: relay.py NODE IN OUT [TAG] (TAG is ignored: a different TAG is a
changed node that the runtime restarts)"""
import sys

import rospy
from std_msgs.msg import String

name, src, dst = sys.argv[1], sys.argv[2], sys.argv[3]
rospy.init_node(name, anonymous=False, disable_signals=True)
pub = rospy.Publisher(dst, String, queue_size=10)
rospy.Subscriber(src, String, pub.publish, queue_size=10, tcp_nodelay=True)
rospy.spin()
