// The authenticated channel (secure_channel.h) and the team key file, without sockets: mutual
// proof of the key, encryption both ways, forged / replayed / reordered messages, another key,
// reflected hellos, malformed handshake messages; key files readable by others are refused; robot
// identities: signatures, key files, the channel binding they sign.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "concord/net/frame_codec.h"
#include "concord/net/identity.h"
#include "concord/net/log_limiter.h"
#include "concord/net/secure_channel.h"
#include "concord/net/team_key.h"

namespace concord::net {
namespace {

struct ChannelPair {
  explicit ChannelPair(const TeamKey& initiator_key, const TeamKey& responder_key)
      : initiator(initiator_key, SecureChannel::Role::kInitiator),
        responder(responder_key, SecureChannel::Role::kResponder) {}
  /// Runs the handshake; true when both sides are established.
  bool handshake() {
    std::string error;
    const auto initiator_proof = initiator.accept_hello(responder.hello(), error);
    const auto responder_proof = responder.accept_hello(initiator.hello(), error);
    if (!initiator_proof || !responder_proof) return false;
    const bool a = responder.accept_proof(*initiator_proof, error);
    const bool b = initiator.accept_proof(*responder_proof, error);
    return a && b;
  }
  SecureChannel initiator;
  SecureChannel responder;
};

TEST(SecureChannel, PeersWithTheKeyExchangeMessagesBothWays) {
  const TeamKey key = TeamKey::generate();
  ChannelPair pair(key, key);
  ASSERT_TRUE(pair.handshake());
  std::string error;
  for (int i = 0; i < 3; ++i) {
    const std::string sealed = pair.initiator.seal("to the responder " + std::to_string(i));
    EXPECT_EQ(sealed.find("responder"), std::string::npos);  // encrypted
    EXPECT_EQ(pair.responder.open(sealed, error), "to the responder " + std::to_string(i));
    EXPECT_EQ(pair.initiator.open(pair.responder.seal("back"), error), "back");
  }
}

TEST(SecureChannel, SealedIntoAFrameBufferAndOpenedIntoAKeptOneAsMessagesOfTheirOwn) {
  // How a session writes: several messages sealed straight into one write buffer behind their
  // frame headers; how it reads: each opened into one plaintext buffer kept between messages.
  const TeamKey key = TeamKey::generate();
  ChannelPair pair(key, key);
  ASSERT_TRUE(pair.handshake());
  const std::vector<std::string> messages = {std::string(3000, 'a'), "b", "",
                                             std::string(70000, 'c')};
  std::string buffer = "xy";  // whatever the buffer held before stays in front
  for (const std::string& message : messages) {
    pair.initiator.seal(message,
                        append_raw_frame_space(message.size() + kChannelOverheadBytes, buffer));
  }
  ASSERT_EQ(buffer.substr(0, 2), "xy");
  FrameDecoder decoder(FrameDecoderOptions{});
  decoder.feed(std::string_view(buffer).substr(2));
  std::string payload, plaintext, error;
  for (const std::string& message : messages) {
    ASSERT_EQ(decoder.next_payload(payload), FrameDecoder::Status::kFrame);
    ASSERT_TRUE(pair.responder.open(payload, plaintext, error)) << error;
    EXPECT_EQ(plaintext, message);  // a shorter message leaves nothing of a longer one
  }
  EXPECT_EQ(decoder.next_payload(payload), FrameDecoder::Status::kNeedMore);

  // A room of the wrong size is a programming error, not a short message.
  std::string room(5, '\0');
  EXPECT_THROW(pair.initiator.seal("payload", room), std::logic_error);
  // A forged message fails into the kept buffer as it does the other way.
  std::string sealed = pair.initiator.seal("payload");
  sealed[sealed.size() / 2] ^= 1;
  EXPECT_FALSE(pair.responder.open(sealed, plaintext, error));
  EXPECT_EQ(pair.responder.stage(), SecureChannel::Stage::kFailed);
}

TEST(SecureChannel, AnotherKeyFailsTheProofOnBothSides) {
  ChannelPair pair(TeamKey::generate(), TeamKey::generate());
  std::string error;
  const auto initiator_proof = pair.initiator.accept_hello(pair.responder.hello(), error);
  const auto responder_proof = pair.responder.accept_hello(pair.initiator.hello(), error);
  ASSERT_TRUE(initiator_proof && responder_proof);  // hellos carry nothing secret
  EXPECT_FALSE(pair.responder.accept_proof(*initiator_proof, error));
  EXPECT_NE(error.find("did not prove"), std::string::npos) << error;
  EXPECT_FALSE(pair.initiator.accept_proof(*responder_proof, error));
  EXPECT_EQ(pair.responder.stage(), SecureChannel::Stage::kFailed);
}

TEST(SecureChannel, ForgedReplayedAndReorderedMessagesFail) {
  const TeamKey key = TeamKey::generate();
  std::string error;
  {
    ChannelPair pair(key, key);
    ASSERT_TRUE(pair.handshake());
    std::string sealed = pair.initiator.seal("payload");
    sealed[sealed.size() / 2] ^= 1;
    EXPECT_FALSE(pair.responder.open(sealed, error));
  }
  {
    ChannelPair pair(key, key);
    ASSERT_TRUE(pair.handshake());
    const std::string first = pair.initiator.seal("one");
    ASSERT_TRUE(pair.responder.open(first, error));
    EXPECT_FALSE(pair.responder.open(first, error));  // replayed
  }
  {
    ChannelPair pair(key, key);
    ASSERT_TRUE(pair.handshake());
    const std::string first = pair.initiator.seal("one");
    const std::string second = pair.initiator.seal("two");
    EXPECT_FALSE(pair.responder.open(second, error));  // reordered
  }
  {
    ChannelPair pair(key, key);
    ASSERT_TRUE(pair.handshake());
    ChannelPair other(key, key);  // a message of another connection with the same key
    ASSERT_TRUE(other.handshake());
    EXPECT_FALSE(pair.responder.open(other.initiator.seal("elsewhere"), error));
  }
}

TEST(SecureChannel, AProofCannotBeReflectedNorAHelloEchoed) {
  const TeamKey key = TeamKey::generate();
  std::string error;
  SecureChannel responder(key, SecureChannel::Role::kResponder);
  EXPECT_FALSE(responder.accept_hello(responder.hello(), error));  // our own hello, echoed
  SecureChannel a(key, SecureChannel::Role::kInitiator);
  SecureChannel b(key, SecureChannel::Role::kInitiator);  // both claim to be the initiator
  const auto proof_a = a.accept_hello(b.hello(), error);
  const auto proof_b = b.accept_hello(a.hello(), error);
  ASSERT_TRUE(proof_a && proof_b);
  EXPECT_FALSE(a.accept_proof(*proof_b, error));  // transcripts differ
  SecureChannel c(key, SecureChannel::Role::kResponder);
  SecureChannel d(key, SecureChannel::Role::kInitiator);
  const auto proof_d = d.accept_hello(c.hello(), error);
  ASSERT_TRUE(proof_d);
  EXPECT_FALSE(d.accept_proof(*proof_d, error));  // our own proof sent back
}

TEST(SecureChannel, MalformedHandshakeMessagesAreRejected) {
  const TeamKey key = TeamKey::generate();
  std::string error;
  for (const std::string& bad :
       {std::string(), std::string(71, 'x'), std::string(72, 'x'), std::string(73, '\0')}) {
    SecureChannel channel(key, SecureChannel::Role::kResponder);
    EXPECT_FALSE(channel.accept_hello(bad, error)) << bad.size();
    EXPECT_EQ(channel.stage(), SecureChannel::Stage::kFailed);
  }
  SecureChannel other(key, SecureChannel::Role::kInitiator);
  std::string version_one = other.hello();
  version_one[7] = 1;
  SecureChannel channel(key, SecureChannel::Role::kResponder);
  EXPECT_FALSE(channel.accept_hello(version_one, error));
  EXPECT_NE(error.find("protocol version 1"), std::string::npos) << error;
  SecureChannel early(key, SecureChannel::Role::kResponder);
  EXPECT_FALSE(early.accept_proof(std::string(56, 'x'), error));
  EXPECT_FALSE(early.open("anything at all here", error));
}

TEST(SecureChannel, BeaconsOpenOnlyWithTheTeamKey) {
  const TeamKey key = TeamKey::generate();
  const std::string sealed = seal_beacon(key, "robot 3 at 10.0.0.3:7100");
  EXPECT_EQ(sealed.find("robot"), std::string::npos);
  EXPECT_EQ(open_beacon(key, sealed), "robot 3 at 10.0.0.3:7100");
  EXPECT_FALSE(open_beacon(TeamKey::generate(), sealed));
  EXPECT_FALSE(open_beacon(key, sealed.substr(0, 10)));
  EXPECT_NE(seal_beacon(key, "x"), seal_beacon(key, "x"));  // fresh nonce every time
}

class TeamKeyFile : public ::testing::Test {
 protected:
  void SetUp() override {
    folder_ =
        std::filesystem::temp_directory_path() / ("concord-key-test-" + std::to_string(::getpid()));
    std::filesystem::remove_all(folder_);
    std::filesystem::create_directories(folder_);
  }
  void TearDown() override { std::filesystem::remove_all(folder_); }
  std::filesystem::path folder_;
};

TEST_F(TeamKeyFile, RoundTripsWithMode0600AndIsNeverOverwritten) {
  const auto path = folder_ / "team.key";
  const TeamKey key = TeamKey::generate();
  write_team_key(path, key);
  struct stat info {};
  ASSERT_EQ(::stat(path.c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 0777, 0600u);
  const TeamKey loaded = load_team_key(path);
  EXPECT_EQ(loaded.format(), key.format());
  EXPECT_THROW(write_team_key(path, TeamKey::generate()), TeamKeyError);
  EXPECT_EQ(load_team_key(path).format(), key.format());
}

TEST_F(TeamKeyFile, AKeyOthersCanReadIsRefusedNamingThePath) {
  const auto path = folder_ / "team.key";
  write_team_key(path, TeamKey::generate());
  ::chmod(path.c_str(), 0644);
  try {
    (void)load_team_key(path);
    FAIL() << "a world-readable key was accepted";
  } catch (const TeamKeyError& error) {
    EXPECT_NE(std::string(error.what()).find(path.string()), std::string::npos) << error.what();
    EXPECT_NE(std::string(error.what()).find("0644"), std::string::npos) << error.what();
  }
  EXPECT_THROW((void)load_team_key(folder_ / "missing.key"), TeamKeyError);
  const auto malformed = folder_ / "malformed.key";
  std::ofstream(malformed) << "concord-team-key-v1 zz\n";
  ::chmod(malformed.c_str(), 0600);
  EXPECT_THROW((void)load_team_key(malformed), TeamKeyError);
}

TEST(SecureChannel, BothEndsShareABindingThatIsFreshForEveryConnection) {
  const TeamKey key = TeamKey::generate();
  ChannelPair first(key, key);
  EXPECT_THROW((void)first.initiator.binding(), std::logic_error);  // no peer hello yet
  ASSERT_TRUE(first.handshake());
  EXPECT_EQ(first.initiator.binding().size(), 32u);
  EXPECT_EQ(first.initiator.binding(), first.responder.binding());
  ChannelPair second(key, key);
  ASSERT_TRUE(second.handshake());
  EXPECT_EQ(second.initiator.binding(), second.responder.binding());
  EXPECT_NE(second.initiator.binding(), first.initiator.binding());
}

TEST(RobotIdentity, SignaturesVerifyOnlyWithTheSignersKeyAndTheSignedBytes) {
  const RobotIdentity alice = RobotIdentity::generate();
  const RobotIdentity bob = RobotIdentity::generate();
  EXPECT_FALSE(alice.public_key() == bob.public_key());
  const std::string message = "owner record 7";
  const std::string signature = alice.sign(message);
  ASSERT_EQ(signature.size(), kSignatureBytes);
  EXPECT_TRUE(alice.public_key().verify(message, signature));
  EXPECT_FALSE(bob.public_key().verify(message, signature));
  EXPECT_FALSE(alice.public_key().verify("owner record 8", signature));
  std::string flipped = signature;
  flipped[10] = static_cast<char>(flipped[10] ^ 1);
  EXPECT_FALSE(alice.public_key().verify(message, flipped));
  EXPECT_FALSE(alice.public_key().verify(message, signature.substr(0, 63)));
  EXPECT_FALSE(alice.public_key().verify(message, ""));
  EXPECT_THROW((void)RobotIdentity().sign(message), std::logic_error);
}

TEST(RobotIdentity, PublicKeysAndKeyTextsRoundTripAndMalformedOnesAreRefused) {
  const RobotIdentity identity = RobotIdentity::generate();
  const std::string hex = identity.public_key().hex();
  EXPECT_EQ(hex.size(), 64u);
  EXPECT_TRUE(PublicKey::parse(hex, "test") == identity.public_key());
  EXPECT_THROW((void)PublicKey::parse(hex.substr(1), "test"), TeamKeyError);
  EXPECT_THROW((void)PublicKey::parse(std::string(64, 'g'), "test"), TeamKeyError);
  const RobotIdentity parsed = RobotIdentity::parse(identity.format(), "test");
  EXPECT_TRUE(parsed.public_key() == identity.public_key());
  EXPECT_TRUE(identity.public_key().verify("m", parsed.sign("m")));
  EXPECT_THROW((void)RobotIdentity::parse("concord-team-key-v1 " + std::string(64, '0'), "test"),
               TeamKeyError);  // a team key is not an identity
  EXPECT_THROW((void)RobotIdentity::parse("concord-identity-key-v1 abc\n", "test"), TeamKeyError);
}

TEST(RobotIdentity, HelloSigningBytesTellRolesRobotsAndConnectionsApart) {
  const std::string binding(32, 'b');
  const std::string base = hello_signing_bytes(binding, true, 2);
  EXPECT_NE(base, hello_signing_bytes(binding, false, 2));
  EXPECT_NE(base, hello_signing_bytes(binding, true, 3));
  EXPECT_NE(base, hello_signing_bytes(std::string(32, 'c'), true, 2));
  EXPECT_EQ(base, hello_signing_bytes(binding, true, 2));
}

TEST_F(TeamKeyFile, IdentityKeysRoundTripWithMode0600AndOthersCannotReadThem) {
  const auto path = folder_ / "robot.identity";
  const RobotIdentity identity = RobotIdentity::generate();
  write_identity(path, identity);
  struct stat info {};
  ASSERT_EQ(::stat(path.c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 0777, 0600u);
  EXPECT_TRUE(load_identity(path).public_key() == identity.public_key());
  EXPECT_THROW(write_identity(path, RobotIdentity::generate()), TeamKeyError);
  EXPECT_TRUE(load_identity(path).public_key() == identity.public_key());
  ::chmod(path.c_str(), 0640);
  try {
    (void)load_identity(path);
    FAIL() << "a group-readable identity key was accepted";
  } catch (const TeamKeyError& error) {
    EXPECT_NE(std::string(error.what()).find(path.string()), std::string::npos) << error.what();
    EXPECT_NE(std::string(error.what()).find("0640"), std::string::npos) << error.what();
  }
}

TEST(LogLimiter, AllowsABurstThenCountsWhatItHoldsBack) {
  LogLimiter limiter({3, std::chrono::hours(1), 2});
  std::uint64_t suppressed = 0;
  for (int i = 0; i < 3; ++i) EXPECT_TRUE(limiter.allow("peer 1 garbage", suppressed));
  for (int i = 0; i < 10; ++i) EXPECT_FALSE(limiter.allow("peer 1 garbage", suppressed));
  EXPECT_TRUE(limiter.allow("peer 2 garbage", suppressed));  // another key has its own burst
  EXPECT_EQ(limiter.suppressed_total(), 10u);
  // Beyond max_keys, new keys share one bucket: memory stays bounded.
  for (int i = 0; i < 100; ++i) (void)limiter.allow("key " + std::to_string(i), suppressed);
  EXPECT_GT(limiter.suppressed_total(), 10u + 90u);
}

}  // namespace
}  // namespace concord::net
