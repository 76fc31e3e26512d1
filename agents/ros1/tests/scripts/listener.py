#!/usr/bin/python3
"""rospy listener for configbot-ros1 tests: prints one line per message
("msg <bytes>") and flushes, so the test can time arrivals.
usage: listener.py NODE_NAME TOPIC"""
import sys

import rospy
from std_msgs.msg import String


def main():
    name, topic = sys.argv[1], sys.argv[2]
    rospy.init_node(name, anonymous=False, disable_signals=True)

    def cb(msg):
        sys.stdout.write("msg %d\n" % len(msg.data))
        sys.stdout.flush()

    rospy.Subscriber(topic, String, cb, queue_size=100, tcp_nodelay=True)
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    rospy.spin()


if __name__ == "__main__":
    main()
