#!/usr/bin/python3
"""rospy talker for the runtime tests. usage: talker.py NODE TOPIC RATE_HZ"""
import sys

import rospy
from std_msgs.msg import String

name, topic, rate = sys.argv[1], sys.argv[2], float(sys.argv[3])
rospy.init_node(name, anonymous=False, disable_signals=True)
pub = rospy.Publisher(topic, String, queue_size=10)
r = rospy.Rate(rate)
i = 0
while not rospy.is_shutdown():
    pub.publish(String(data="m%d" % i))
    i += 1
    r.sleep()
