// Read Device Identification (function 43, MEI type 14), frame by frame as Modbus Application
// Protocol v1.1b3 §6.21 lays them out: request PDU 2B 0E <Read Device ID code> <Object Id>;
// response PDU 2B 0E <code> <conformity level> <more follows> <next object id> <number of
// objects>, then each object as <id> <length> <value>.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "protocol/device_identification.hpp"

namespace ioport::modbus {
namespace {

using Bytes = std::vector<std::uint8_t>;

const DeviceIdentity identity{"ACME", "IO8", "1.2", "man:x", "Gate", "hub8u", "press"};

Bytes answer(const Bytes& request, const DeviceIdentity& objects = identity) {
    auto response = read_device_identification(request, objects);
    EXPECT_TRUE(response.has_value()) << "exception " << static_cast<int>(response.error());
    return response.value_or(Bytes{});
}

Exception refusal(const Bytes& request) {
    const auto response = read_device_identification(request, identity);
    EXPECT_FALSE(response.has_value());
    return response ? Exception{} : response.error();
}

// An object as it appears in a response: id, length, the characters.
Bytes object(std::uint8_t id, const std::string& value) {
    Bytes bytes{id, static_cast<std::uint8_t>(value.size())};
    for (const char c : value)
        bytes.push_back(static_cast<std::uint8_t>(c));
    return bytes;
}

// (Byte by byte: GCC 12 at -O2 warns of a bounds overflow in vector::insert here that is not.)
Bytes operator+(Bytes a, const Bytes& b) {
    for (const auto byte : b)
        a.push_back(byte);
    return a;
}

TEST(DeviceIdentification, BasicStreamFromTheStartAnswersObjects0To2) {
    const Bytes request{
        0x2B,  // function: encapsulated interface transport
        0x0E,  // MEI type: read device identification
        0x01,  // Read Device ID code: basic, stream access
        0x00,  // object id: start at VendorName
    };
    const Bytes expected =
        Bytes{
            0x2B, 0x0E,  // function, MEI type
            0x01,        // Read Device ID code, echoed
            0x82,        // conformity level: regular identification, stream and individual access
            0x00,        // more follows: no
            0x00,        // next object id: 0 when nothing follows
            0x03,        // number of objects
        } +
        object(0x00, "ACME") + object(0x01, "IO8") + object(0x02, "1.2");
    EXPECT_EQ(answer(request), expected);
}

TEST(DeviceIdentification, RegularAndExtendedStreamsAnswerObjects0To6) {
    const Bytes objects = object(0x00, "ACME") + object(0x01, "IO8") + object(0x02, "1.2") +
                          object(0x03, "man:x") + object(0x04, "Gate") + object(0x05, "hub8u") +
                          object(0x06, "press");
    EXPECT_EQ(answer({0x2B, 0x0E, 0x02, 0x00}),
              Bytes({0x2B, 0x0E, 0x02, 0x82, 0x00, 0x00, 0x07}) + objects);
    // No extended objects: code 03 answers the regular ones, and says it answered code 03.
    EXPECT_EQ(answer({0x2B, 0x0E, 0x03, 0x00}),
              Bytes({0x2B, 0x0E, 0x03, 0x82, 0x00, 0x00, 0x07}) + objects);
}

TEST(DeviceIdentification, AStreamStartsAtTheRequestedObject) {
    EXPECT_EQ(answer({0x2B, 0x0E, 0x02, 0x05}), Bytes({0x2B, 0x0E, 0x02, 0x82, 0x00, 0x00, 0x02}) +
                                                    object(0x05, "hub8u") + object(0x06, "press"));
    EXPECT_EQ(answer({0x2B, 0x0E, 0x01, 0x02}),
              Bytes({0x2B, 0x0E, 0x01, 0x82, 0x00, 0x00, 0x01}) + object(0x02, "1.2"));
}

// §6.21: "If the Object Id does not match any known object, the server responds as if object 0
// were pointed out (restart at the beginning)".
TEST(DeviceIdentification, AStreamFromAnObjectOutsideItsCategoryRestartsAt0) {
    const auto basic = Bytes({0x2B, 0x0E, 0x01, 0x82, 0x00, 0x00, 0x03}) + object(0x00, "ACME") +
                       object(0x01, "IO8") + object(0x02, "1.2");
    EXPECT_EQ(answer({0x2B, 0x0E, 0x01, 0x04}), basic);  // ProductName is a regular object
    EXPECT_EQ(answer({0x2B, 0x0E, 0x01, 0xFF}), basic);
    const auto regular = answer({0x2B, 0x0E, 0x02, 0x07});
    ASSERT_GE(regular.size(), 8u);
    EXPECT_EQ(regular[6], 7);     // number of objects
    EXPECT_EQ(regular[7], 0x00);  // the first is VendorName
    auto extended = answer({0x2B, 0x0E, 0x03, 0x80});
    ASSERT_EQ(extended.size(), regular.size());
    EXPECT_EQ(extended[2], 0x03);  // the code, echoed
    extended[2] = 0x02;
    EXPECT_EQ(extended, regular);
}

TEST(DeviceIdentification, IndividualAccessAnswersOneObject) {
    const Bytes request{
        0x2B, 0x0E,  // function, MEI type
        0x04,        // Read Device ID code: one specific object
        0x05,        // object id: ModelName
    };
    EXPECT_EQ(answer(request), Bytes({
                                   0x2B, 0x0E, 0x04, 0x82,
                                   0x00,  // more follows: never with individual access
                                   0x00,  // next object id
                                   0x01,  // number of objects
                               }) + object(0x05, "hub8u"));
    EXPECT_EQ(answer({0x2B, 0x0E, 0x04, 0x00}),
              Bytes({0x2B, 0x0E, 0x04, 0x82, 0x00, 0x00, 0x01}) + object(0x00, "ACME"));
}

TEST(DeviceIdentification, RefusalsFollowTheSpecification) {
    // An object that individual access does not know: illegal data address.
    EXPECT_EQ(refusal({0x2B, 0x0E, 0x04, 0x07}), Exception::illegal_data_address);
    EXPECT_EQ(refusal({0x2B, 0x0E, 0x04, 0x80}), Exception::illegal_data_address);
    // A Read Device ID code other than 01-04: illegal data value.
    EXPECT_EQ(refusal({0x2B, 0x0E, 0x00, 0x00}), Exception::illegal_data_value);
    EXPECT_EQ(refusal({0x2B, 0x0E, 0x05, 0x00}), Exception::illegal_data_value);
    // A PDU of the wrong length: illegal data value.
    EXPECT_EQ(refusal({0x2B, 0x0E, 0x01}), Exception::illegal_data_value);
    EXPECT_EQ(refusal({0x2B, 0x0E, 0x01, 0x00, 0x00}), Exception::illegal_data_value);
    // Another MEI type (0x0D: CANopen general reference) or none: illegal function.
    EXPECT_EQ(refusal({0x2B, 0x0D, 0x01, 0x00}), Exception::illegal_function);
    EXPECT_EQ(refusal({0x2B}), Exception::illegal_function);
}

// Seven 64-character objects do not fit one 253-byte PDU: 7 + 3 × 66 = 205 bytes, and a fourth
// object would make 271. The client asks again from "next object id" until nothing follows.
TEST(DeviceIdentification, ObjectsThatDoNotFitFollowInTheNextTransaction) {
    DeviceIdentity big;
    for (std::size_t i = 0; i < big.size(); ++i)
        big[i] = std::string(64, static_cast<char>('A' + i));
    auto first = answer({0x2B, 0x0E, 0x02, 0x00}, big);
    EXPECT_EQ(first.size(), 205u);
    EXPECT_EQ(Bytes(first.begin(), first.begin() + 7), Bytes({0x2B, 0x0E, 0x02, 0x82,
                                                              0xFF,     // more follows
                                                              0x03,     // next object id
                                                              0x03}));  // number of objects
    auto second = answer({0x2B, 0x0E, 0x02, 0x03}, big);
    EXPECT_EQ(Bytes(second.begin(), second.begin() + 7),
              Bytes({0x2B, 0x0E, 0x02, 0x82, 0xFF, 0x06, 0x03}));
    EXPECT_EQ(second[7], 0x03);
    const auto last = answer({0x2B, 0x0E, 0x02, 0x06}, big);
    EXPECT_EQ(last, Bytes({0x2B, 0x0E, 0x02, 0x82, 0x00, 0x00, 0x01}) + object(0x06, big[6]));
}

}  // namespace
}  // namespace ioport::modbus
