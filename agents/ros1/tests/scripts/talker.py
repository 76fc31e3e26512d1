#!/usr/bin/python3
"""rospy talker for configbot-ros1 tests.
usage: talker.py NODE_NAME TOPIC RATE_HZ [--latch]
With --latch it publishes one latched message and keeps running."""
import sys

import rospy
from std_msgs.msg import String


def main():
    name, topic, rate = sys.argv[1], sys.argv[2], float(sys.argv[3])
    latch = "--latch" in sys.argv[4:]
    rospy.init_node(name, anonymous=False, disable_signals=True)
    pub = rospy.Publisher(topic, String, queue_size=100, latch=latch)
    if latch:
        pub.publish(String(data="latched hello"))
        rospy.spin()
        return
    r = rospy.Rate(rate)
    i = 0
    while not rospy.is_shutdown():
        pub.publish(String(data="hello %d" % i))
        i += 1
        r.sleep()


if __name__ == "__main__":
    main()
