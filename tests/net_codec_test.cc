// The frame codec alone (no sockets): round trips, stream splitting, and every rejection.
#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include <set>
#include <string>
#include <vector>

#include "concord/net/frame_codec.h"
#include "concord/v1/concord.pb.h"

namespace concord::net {
namespace {

using Status = FrameDecoder::Status;

v1::Envelope header(std::uint32_t sender = 3, std::string team = "alpha") {
  v1::Envelope envelope;
  envelope.set_protocol_version(kProtocolVersion);
  envelope.set_team(std::move(team));
  envelope.set_sender(sender);
  envelope.set_seq(17);
  envelope.set_round(42);
  return envelope;
}

/// One envelope of every body type, with every field set to something non-default.
std::vector<v1::Envelope> every_message_type() {
  std::vector<v1::Envelope> all;

  v1::Envelope hello = header();
  hello.mutable_hello()->set_robot_id(3);
  hello.mutable_hello()->set_listen_address("10.0.0.3");
  hello.mutable_hello()->set_listen_port(47001);
  hello.mutable_hello()->add_capabilities("consensus.lockstep");
  hello.mutable_hello()->add_capabilities("consensus.async");
  hello.mutable_hello()->set_degree(2);
  hello.mutable_hello()->set_instance(0x0123456789abcdefULL);
  all.push_back(hello);

  v1::Envelope heartbeat = header();
  heartbeat.mutable_heartbeat()->set_time_ns(123456789012345ULL);
  heartbeat.mutable_heartbeat()->set_echo_time_ns(123456789000000ULL);
  heartbeat.mutable_heartbeat()->set_echo_delay_ns(5000);
  heartbeat.mutable_heartbeat()->set_degree(4);
  all.push_back(heartbeat);

  v1::Envelope full_set = header();
  full_set.mutable_landmark_set()->set_round(42);
  for (std::int64_t id : {1LL, 5LL, 9LL, 1000000000000LL})
    full_set.mutable_landmark_set()->add_ids(id);
  full_set.mutable_landmark_set()->set_degree(2);
  all.push_back(full_set);

  v1::Envelope delta = header();
  delta.mutable_landmark_set()->set_delta(true);
  delta.mutable_landmark_set()->add_added(7);
  delta.mutable_landmark_set()->add_removed(-3);
  all.push_back(delta);

  v1::Envelope marginal = header();
  v1::Marginal& m = *marginal.mutable_marginal();
  m.set_round(42);
  m.add_landmark_ids(5);
  m.add_landmark_ids(9);
  for (double value : {1.0, -2.5, 3.25, 4.0, 5.5, -6.75}) m.add_mean(value);
  v1::CovarianceBlock& block = *m.add_blocks();
  block.set_landmarks(2);
  for (int i = 0; i < 21; ++i) block.add_packed_upper(0.01 * (i + 1));
  m.set_degree(3);
  all.push_back(marginal);

  v1::Envelope goodbye = header();
  goodbye.mutable_goodbye()->set_reason("end of frames");
  goodbye.mutable_goodbye()->set_last_round(99);
  all.push_back(goodbye);

  v1::Envelope sensor = header();
  v1::SensorFrame& frame = *sensor.mutable_sensor_frame();
  frame.set_frame(12);
  frame.set_timestamp(1.25);
  v1::Pose& pose = *frame.mutable_odometry();
  pose.set_x(0.5);
  pose.set_y(-0.1);
  pose.set_z(0.01);
  pose.set_qw(0.99);
  pose.set_qx(0.01);
  pose.set_qy(0.02);
  pose.set_qz(0.03);
  for (int i = 0; i < 21; ++i) frame.add_odometry_covariance(i * 1e-3);
  v1::StereoObservation& object = *frame.add_objects();
  object.set_id(5);
  object.set_u_left(100.5);
  object.set_v_left(200.25);
  object.set_u_right(90.0);
  object.set_v_right(200.0);
  *frame.add_features() = object;
  frame.set_last(true);
  all.push_back(sensor);
  return all;
}

FrameDecoderOptions alpha_options(std::size_t max_frame_bytes = kDefaultMaxFrameBytes) {
  return FrameDecoderOptions{max_frame_bytes, std::string("alpha")};
}

/// A raw 4-byte big-endian length prefix.
std::string length_prefix(std::uint32_t length) {
  return {static_cast<char>(length >> 24), static_cast<char>(length >> 16),
          static_cast<char>(length >> 8), static_cast<char>(length)};
}

bool same(const v1::Envelope& a, const v1::Envelope& b) {
  return google::protobuf::util::MessageDifferencer::Equals(a, b);
}

TEST(FrameCodec, FrameIsBigEndianLengthThenPayload) {
  const v1::Envelope envelope = every_message_type()[4];
  const std::string frame = encode_frame(envelope);
  ASSERT_EQ(frame.size(), kFrameHeaderBytes + envelope.ByteSizeLong());
  EXPECT_EQ(frame.substr(0, 4), length_prefix(static_cast<std::uint32_t>(envelope.ByteSizeLong())));
  EXPECT_EQ(frame.substr(4), envelope.SerializeAsString());
}

TEST(FrameCodec, RoundTripsEveryMessageType) {
  const std::vector<v1::Envelope> all = every_message_type();
  ASSERT_EQ(all.size(), 7u);
  std::set<int> bodies;
  for (const v1::Envelope& original : all) {
    SCOPED_TRACE(original.ShortDebugString());
    bodies.insert(original.body_case());
    FrameDecoder decoder(alpha_options());
    decoder.feed(encode_frame(original));
    v1::Envelope decoded;
    ASSERT_EQ(decoder.next(decoded), Status::kFrame);
    EXPECT_TRUE(same(decoded, original));
    EXPECT_EQ(decoder.next(decoded), Status::kNeedMore);
    EXPECT_EQ(decoder.buffered_bytes(), 0u);
    EXPECT_FALSE(decoder.failed());
  }
  EXPECT_EQ(bodies.size(), 6u);  // all six oneof bodies
}

TEST(FrameCodec, SeveralFramesInOneChunk) {
  const std::vector<v1::Envelope> all = every_message_type();
  std::string stream;
  for (const v1::Envelope& envelope : all) append_frame(envelope, stream);
  FrameDecoder decoder(alpha_options());
  decoder.feed(stream);
  v1::Envelope decoded;
  for (const v1::Envelope& original : all) {
    ASSERT_EQ(decoder.next(decoded), Status::kFrame);
    EXPECT_TRUE(same(decoded, original));
  }
  EXPECT_EQ(decoder.next(decoded), Status::kNeedMore);
}

TEST(FrameCodec, FramesSplitByteByByte) {
  const std::vector<v1::Envelope> all = every_message_type();
  std::string stream;
  for (const v1::Envelope& envelope : all) append_frame(envelope, stream);
  FrameDecoder decoder(alpha_options());
  std::vector<v1::Envelope> received;
  v1::Envelope decoded;
  for (char byte : stream) {
    decoder.feed(std::string_view(&byte, 1));
    Status status;
    while ((status = decoder.next(decoded)) == Status::kFrame) received.push_back(decoded);
    ASSERT_EQ(status, Status::kNeedMore);
  }
  ASSERT_EQ(received.size(), all.size());
  for (std::size_t i = 0; i < all.size(); ++i) EXPECT_TRUE(same(received[i], all[i]));
  EXPECT_EQ(decoder.buffered_bytes(), 0u);
}

TEST(FrameCodec, TruncatedFrameWaitsWithoutError) {
  const std::string frame = encode_frame(every_message_type()[4]);
  FrameDecoder decoder(alpha_options());
  v1::Envelope decoded;
  decoder.feed(frame.substr(0, 2));  // half a header
  EXPECT_EQ(decoder.next(decoded), Status::kNeedMore);
  decoder.feed(frame.substr(2, frame.size() - 3));  // all but the last byte
  EXPECT_EQ(decoder.next(decoded), Status::kNeedMore);
  EXPECT_EQ(decoder.next(decoded), Status::kNeedMore);
  EXPECT_FALSE(decoder.failed());
  EXPECT_EQ(decoder.buffered_bytes(), frame.size() - 1);
  decoder.feed(frame.substr(frame.size() - 1));
  EXPECT_EQ(decoder.next(decoded), Status::kFrame);
}

TEST(FrameCodec, OversizedLengthIsRejectedBeforeThePayloadArrives) {
  FrameDecoder decoder(alpha_options(1024));
  decoder.feed(length_prefix(1025));  // header only
  v1::Envelope decoded;
  ASSERT_EQ(decoder.next(decoded), Status::kError);
  EXPECT_EQ(decoder.error().kind, FrameErrorKind::kOversized);
  EXPECT_NE(decoder.error().reason.find("1025"), std::string::npos) << decoder.error().reason;
  EXPECT_EQ(decoder.buffered_bytes(), 0u);

  FrameDecoder huge(alpha_options());
  huge.feed(length_prefix(0xffffffffu));
  EXPECT_EQ(huge.next(decoded), Status::kError);
  EXPECT_EQ(huge.error().kind, FrameErrorKind::kOversized);
}

TEST(FrameCodec, FrameOfExactlyTheMaximumIsAccepted) {
  v1::Envelope envelope = header();
  envelope.mutable_goodbye()->set_reason(std::string(100, 'x'));
  const std::string frame = encode_frame(envelope);
  const std::size_t payload = frame.size() - kFrameHeaderBytes;
  FrameDecoder exact(alpha_options(payload));
  exact.feed(frame);
  v1::Envelope decoded;
  EXPECT_EQ(exact.next(decoded), Status::kFrame);
  FrameDecoder smaller(alpha_options(payload - 1));
  smaller.feed(frame);
  EXPECT_EQ(smaller.next(decoded), Status::kError);
  EXPECT_EQ(smaller.error().kind, FrameErrorKind::kOversized);
}

TEST(FrameCodec, GarbagePayloadIsAnError) {
  FrameDecoder decoder(alpha_options());
  decoder.feed(length_prefix(6) + std::string(6, '\xff'));
  v1::Envelope decoded;
  ASSERT_EQ(decoder.next(decoded), Status::kError);
  EXPECT_EQ(decoder.error().kind, FrameErrorKind::kGarbage);
  EXPECT_FALSE(decoder.error().reason.empty());
}

TEST(FrameCodec, ParsableBytesWithoutAVersionAreRejected) {
  // Valid protobuf wire format (field 20, varint 1) but not a v1 envelope: no version.
  FrameDecoder decoder(alpha_options());
  decoder.feed(length_prefix(3) + std::string("\xa0\x01\x01", 3));
  v1::Envelope decoded;
  ASSERT_EQ(decoder.next(decoded), Status::kError);
  EXPECT_EQ(decoder.error().kind, FrameErrorKind::kWrongVersion);
}

TEST(FrameCodec, ZeroLengthIsAnError) {
  FrameDecoder decoder(alpha_options());
  decoder.feed(length_prefix(0));
  v1::Envelope decoded;
  ASSERT_EQ(decoder.next(decoded), Status::kError);
  EXPECT_EQ(decoder.error().kind, FrameErrorKind::kZeroLength);
}

TEST(FrameCodec, WrongVersionIsAnError) {
  v1::Envelope envelope = every_message_type()[1];
  envelope.set_protocol_version(1);  // a v1 daemon
  FrameDecoder decoder(alpha_options());
  decoder.feed(encode_frame(envelope));
  v1::Envelope decoded;
  ASSERT_EQ(decoder.next(decoded), Status::kError);
  EXPECT_EQ(decoder.error().kind, FrameErrorKind::kWrongVersion);
  EXPECT_NE(decoder.error().reason.find("version 1"), std::string::npos) << decoder.error().reason;
}

TEST(FrameCodec, WrongTeamIsAnErrorUnlessAnyTeamIsAccepted) {
  v1::Envelope envelope = every_message_type()[1];
  envelope.set_team("bravo");
  FrameDecoder decoder(alpha_options());
  decoder.feed(encode_frame(envelope));
  v1::Envelope decoded;
  ASSERT_EQ(decoder.next(decoded), Status::kError);
  EXPECT_EQ(decoder.error().kind, FrameErrorKind::kWrongTeam);
  EXPECT_NE(decoder.error().reason.find("bravo"), std::string::npos) << decoder.error().reason;

  FrameDecoder any_team(FrameDecoderOptions{kDefaultMaxFrameBytes, std::nullopt});
  any_team.feed(encode_frame(envelope));
  EXPECT_EQ(any_team.next(decoded), Status::kFrame);
  EXPECT_EQ(decoded.team(), "bravo");
}

TEST(FrameCodec, FramesBeforeAnErrorAreDeliveredAndTheErrorIsSticky) {
  const v1::Envelope good = every_message_type()[0];
  std::string stream = encode_frame(good) + length_prefix(0) + encode_frame(good);
  FrameDecoder decoder(alpha_options());
  decoder.feed(stream);
  v1::Envelope decoded;
  ASSERT_EQ(decoder.next(decoded), Status::kFrame);
  EXPECT_TRUE(same(decoded, good));
  EXPECT_EQ(decoder.next(decoded), Status::kError);
  decoder.feed(encode_frame(good));  // ignored: the stream is broken
  EXPECT_EQ(decoder.next(decoded), Status::kError);
  EXPECT_EQ(decoder.error().kind, FrameErrorKind::kZeroLength);
  EXPECT_EQ(decoder.buffered_bytes(), 0u);
}

TEST(FrameCodec, BufferStaysBoundedOverALongStream) {
  const std::string frame = encode_frame(every_message_type()[4]);
  FrameDecoder decoder(alpha_options());
  v1::Envelope decoded;
  std::size_t frames = 0;
  // Chunks that never align with frame boundaries.
  std::string stream;
  for (int i = 0; i < 500; ++i) stream += frame;
  for (std::size_t offset = 0; offset < stream.size(); offset += 77) {
    decoder.feed(std::string_view(stream).substr(offset, 77));
    while (decoder.next(decoded) == Status::kFrame) ++frames;
    EXPECT_LT(decoder.buffered_bytes(), frame.size() + 77);
  }
  EXPECT_EQ(frames, 500u);
}

TEST(FrameCodec, ErrorKindsHaveNames) {
  EXPECT_EQ(to_string(FrameErrorKind::kOversized), "oversized");
  EXPECT_EQ(to_string(FrameErrorKind::kGarbage), "garbage");
  EXPECT_EQ(to_string(FrameErrorKind::kZeroLength), "zero-length");
  EXPECT_EQ(to_string(FrameErrorKind::kWrongVersion), "wrong-version");
  EXPECT_EQ(to_string(FrameErrorKind::kWrongTeam), "wrong-team");
}

}  // namespace
}  // namespace concord::net
