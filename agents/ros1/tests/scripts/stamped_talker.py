#!/usr/bin/python3
"""rospy talker of stamped messages for configbot-ros1 tests.
usage: stamped_talker.py NODE_NAME TOPIC RATE_HZ AGE_S
Publishes geometry_msgs/PointStamped whose header stamp is AGE_S seconds
before the moment it is published, as a frame that took that long through
a pipeline would arrive."""
import sys

import rospy
from geometry_msgs.msg import PointStamped


def main():
    name, topic = sys.argv[1], sys.argv[2]
    rate, age = float(sys.argv[3]), rospy.Duration.from_sec(float(sys.argv[4]))
    rospy.init_node(name, anonymous=False, disable_signals=True)
    pub = rospy.Publisher(topic, PointStamped, queue_size=100)
    r = rospy.Rate(rate)
    while not rospy.is_shutdown():
        m = PointStamped()
        m.header.stamp = rospy.Time.now() - age
        pub.publish(m)
        r.sleep()


if __name__ == "__main__":
    main()
