#!/usr/bin/python3
"""rospy publisher for the simnode tests: publishes std_msgs/UInt8MultiArray
at HZ with a BYTES-long data array that starts with the simnode header
(seq u64 LE, stamp ns u64 LE).
usage: talk.py NODE_NAME TOPIC HZ BYTES"""
import struct
import sys
import time

import rospy
from std_msgs.msg import UInt8MultiArray


def main():
    name, topic, hz, size = sys.argv[1], sys.argv[2], float(sys.argv[3]), int(sys.argv[4])
    rospy.init_node(name, anonymous=False, disable_signals=True)
    pub = rospy.Publisher(topic, UInt8MultiArray, queue_size=10, tcp_nodelay=True)
    rate = rospy.Rate(hz)
    seq = 0
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    while not rospy.is_shutdown():
        head = struct.pack("<QQ", seq, time.time_ns())
        pub.publish(UInt8MultiArray(data=head + bytes(max(0, size - 16))))
        seq += 1
        rate.sleep()


if __name__ == "__main__":
    main()
