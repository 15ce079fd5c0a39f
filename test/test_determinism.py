"""Comparing two runs message for message (quadrivio.determinism), ROS-free."""

from quadrivio.determinism import NOT_SEQUENCED, compare


def test_identical_streams_are_the_same():
    a = {("/x", "/p"): [b"1", b"2"], ("/tf", "/q"): [b"a"]}
    diffs, n = compare(a, {k: list(v) for k, v in a.items()})
    assert diffs == [] and n == 2


def test_each_publisher_of_a_topic_is_its_own_stream():
    # /tf from two publishers: their interleaving is the scheduler's, each sequence must repeat
    a = {("/tf", "/sim"): [b"s1", b"s2"], ("/tf", "/loc"): [b"l1"]}
    b = {("/tf", "/loc"): [b"l1"], ("/tf", "/sim"): [b"s1", b"s2"]}
    assert compare(a, b)[0] == []


def test_differences_are_named_with_the_first_differing_message():
    a = {("/x", "/p"): [b"1", b"2", b"3"], ("/y", "/p"): [b"1"], ("/z", "/p"): [b"1"]}
    b = {("/x", "/p"): [b"1", b"9", b"3"], ("/y", "/p"): [b"1", b"2"]}
    diffs, n = compare(a, b)
    assert n == 3
    got = {(d.topic, d.count_a, d.count_b, d.first_difference) for d in diffs}
    assert got == {("/x", 3, 3, 1), ("/y", 1, 2, None), ("/z", 1, 0, None)}
    assert "message 1 differs" in [d for d in diffs if d.topic == "/x"][0].describe()


def test_robot_state_publishers_tf_is_left_out_and_its_input_is_not():
    """robot_state_publisher, no lockstep member, subscribes to /joint_states with a queue of
    one: starved of CPU it drops a joint state and its /tf is a message short (439 against
    440 in a fresh clone's make test). Its /tf is left out; the joint states are not."""
    rsp = ("/tf", "/robot_state_publisher")
    assert rsp in NOT_SEQUENCED
    a = {rsp: [b"t1", b"t2", b"t3"], ("/tf", "/sim"): [b"s1"], ("/joint_states", "/sim"): [b"j1", b"j2", b"j3"]}
    b = {rsp: [b"t1", b"t3"], ("/tf", "/sim"): [b"s1"], ("/joint_states", "/sim"): [b"j1", b"j2", b"j3"]}
    diffs, n = compare(a, b)
    assert diffs == [] and n == 2
    b[("/joint_states", "/sim")] = [b"j1", b"j3"]
    assert [(d.topic, d.publisher) for d in compare(a, b)[0]] == [("/joint_states", "/sim")]
    b[("/tf", "/sim")] = [b"s9"]  # another node's /tf is still compared
    assert ("/tf", "/sim") in [(d.topic, d.publisher) for d in compare(a, b)[0]]


def test_a_run_cut_short_from_outside_is_the_same_with_prefix():
    a = {("/x", "/p"): [b"1", b"2", b"3"], ("/y", "/p"): [b"1"]}
    b = {("/x", "/p"): [b"1", b"2"], ("/y", "/p"): [b"1", b"2"]}
    assert len(compare(a, b)[0]) == 2
    assert compare(a, b, prefix=True)[0] == []
    b[("/x", "/p")] = [b"1", b"9"]  # a difference inside the common part is still one
    assert [d.topic for d in compare(a, b, prefix=True)[0]] == ["/x"]
    assert [d.topic for d in compare(a, {("/x", "/p"): [b"1", b"2", b"3"]}, prefix=True)[0]] == ["/y"]  # missing


def test_static_transforms_compare_without_their_stamps(tmp_path):
    """robot_state_publisher stamps /tf_static with the first /clock it reads (0.02 s in one
    lockstep run, 0.03 s in the next of the same seed): the stamps are left out, the
    transforms themselves are not."""
    import rosbag
    import rospy
    from geometry_msgs.msg import TransformStamped
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from quadrivio.ros.bag import streams

    def bag(name, stamp, x, chatter="hi"):
        t = TransformStamped()
        t.header.stamp, t.header.frame_id, t.child_frame_id = rospy.Time.from_sec(stamp), "base_link", "laser_front"
        t.transform.translation.x, t.transform.rotation.w = x, 1.0
        path = str(tmp_path / name)
        with rosbag.Bag(path, "w") as b:
            b.write("/tf_static", TFMessage(transforms=[t]), rospy.Time.from_sec(stamp))
            b.write("/chatter", String(data=chatter), rospy.Time.from_sec(stamp))
        return streams(path)

    a = bag("a.bag", 0.02, 1.10)
    assert compare(a, bag("b.bag", 0.03, 1.10))[0] == []
    assert [d.topic for d in compare(a, bag("c.bag", 0.02, 1.20))[0]] == ["/tf_static"]  # moved: differs
    assert [d.topic for d in compare(a, bag("d.bag", 0.02, 1.10, "ho"))[0]] == ["/chatter"]
