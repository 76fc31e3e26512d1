#!/usr/bin/python3
"""rospy talker for the runtime tests. usage: talker.py NODE TOPIC RATE_HZ [PAD_BYTES]"""
import sys

import rospy
from std_msgs.msg import String

name, topic, rate = sys.argv[1], sys.argv[2], float(sys.argv[3])
pad = "x" * (int(sys.argv[4]) if len(sys.argv) > 4 else 0)
rospy.init_node(name, anonymous=False, disable_signals=True)
pub = rospy.Publisher(topic, String, queue_size=10)
r = rospy.Rate(rate)
i = 0
while not rospy.is_shutdown():
    pub.publish(String(data="m%d%s" % (i, pad)))
    i += 1
    r.sleep()
